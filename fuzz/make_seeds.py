#!/usr/bin/env python3
"""Writes the fuzz targets' seed corpora (fuzz/corpus/<target>/): small valid inputs of every
variant each parser knows, plus a few near-misses. Run once; the output is committed."""
import gzip
import os
import struct
import zlib

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "corpus")


def put(target, name, data):
    d = os.path.join(ROOT, target)
    os.makedirs(d, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def record(kind, seq, dims=(0, 0, 0), vtype=1, payload=b""):
    head = struct.pack("<4sHHQQHHHBB3f3fI", b"USV1", 1, kind, seq, 1000 * seq, *dims, vtype, 0,
                       0.5, 0.5, 0.5, 1.0, 2.0, 3.0, len(payload))
    head += struct.pack("<I", zlib.crc32(head) & 0xFFFFFFFF)
    if kind != 1:
        return head
    return head + payload + struct.pack("<I", zlib.crc32(payload) & 0xFFFFFFFF)


def probe_stream():
    vol8 = record(1, 0, (4, 3, 2), 1, bytes(range(24)))
    vol16 = record(1, 1, (2, 2, 2), 2, bytes(range(16)))
    hb = record(2, 2)
    eos = record(3, 3)
    # First byte of every input: the chunk size the target feeds with.
    put("fuzz_probe_stream", "volumes", b"\x07" + vol8 + vol16 + hb + eos)
    put("fuzz_probe_stream", "gap", b"\x40" + vol8 + record(1, 5, (4, 3, 2), 1, bytes(24)))
    bad = bytearray(vol8)
    bad[70] ^= 0xFF  # payload CRC mismatch
    put("fuzz_probe_stream", "corrupt_then_good", b"\x00" + bytes(bad) + b"junk" + vol16)
    put("fuzz_probe_stream", "truncated", b"\xff" + vol8[:50])


def nrrd():
    raw = bytes(range(24))
    head = ("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 3 2\nspace: left-posterior-superior\n"
            "space directions: (0.5,0,0) (0,0.5,0) (0,0,1)\nspace origin: (1,2,3)\n")
    put("fuzz_nrrd", "raw", head + "encoding: raw\n\n" + raw.decode("latin1"))
    put("fuzz_nrrd", "gzip", (head + "encoding: gzip\n\n").encode() + gzip.compress(raw))
    put("fuzz_nrrd", "detached", head + "encoding: raw\ndata file: data.raw\n\n" +
        raw.decode("latin1"))
    put("fuzz_nrrd", "ras_uint16", "NRRD0005\ntype: unsigned short\ndimension: 3\nsizes: 2 2 2\n"
        "endian: little\nspace: right-anterior-superior\n"
        "space directions: (-1,0,0) (0,1,0) (0,0,2)\nencoding: raw\n\n" + "\x01\x00" * 8)
    put("fuzz_nrrd", "float_ascii", "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 1 1\n"
        "spacings: 1 1 1\nencoding: ascii\n\n1.5 2.5\n")
    put("fuzz_nrrd", "long_line", "NRRD0004\n" + "0" * 1200 + "\n\n")


def metaimage():
    raw = bytes(range(24))
    head = ("ObjectType = Image\nNDims = 3\nDimSize = 4 3 2\nElementSpacing = 0.5 0.5 1\n"
            "Offset = 1 2 3\nTransformMatrix = 1 0 0 0 1 0 0 0 1\nElementType = MET_UCHAR\n")
    put("fuzz_metaimage", "raw", head + "ElementDataFile = LOCAL\n" + raw.decode("latin1"))
    put("fuzz_metaimage", "zlib", (head + "CompressedData = True\nCompressedDataSize = %d\n"
                                   "ElementDataFile = LOCAL\n" % len(zlib.compress(raw))).encode()
        + zlib.compress(raw))
    put("fuzz_metaimage", "detached", head + "ElementDataFile = data.raw\n" + raw.decode("latin1"))
    put("fuzz_metaimage", "short_msb", "ObjectType = Image\nNDims = 3\nDimSize = 2 2 1\n"
        "BinaryDataByteOrderMSB = True\nElementType = MET_SHORT\nElementDataFile = LOCAL\n" +
        "\x00\x01" * 4)


def nifti():
    # NIfTI-1 single file: 348-byte header, 4 bytes extension flag, data at vox_offset 352.
    def nii(dims, datatype, bitpix, data, qform=1, pixdim=(0.5, 0.5, 1.0)):
        h = bytearray(348)
        struct.pack_into("<i", h, 0, 348)
        struct.pack_into("<8h", h, 40, 3, *dims, 1, 1, 1, 1)
        struct.pack_into("<hh", h, 70, datatype, bitpix)
        struct.pack_into("<8f", h, 76, 1.0, *pixdim, 1, 1, 1, 1)
        struct.pack_into("<f", h, 108, 352.0)
        struct.pack_into("<f", h, 112, 1.0)  # scl_slope
        struct.pack_into("<hh", h, 252, qform, 0)
        struct.pack_into("<6f", h, 256, 0, 0, 0, 1.0, 2.0, 3.0)  # quatern b c d, offsets
        h[344:348] = b"n+1\0"
        return bytes(h) + b"\0\0\0\0" + data
    put("fuzz_nifti", "uint8", nii((4, 3, 2), 2, 8, bytes(range(24))))
    put("fuzz_nifti", "int16", nii((2, 2, 2), 4, 16, struct.pack("<8h", *range(8))))
    put("fuzz_nifti", "float_noqform", nii((2, 2, 1), 16, 32, struct.pack("<4f", 0, 1, 2, 3), 0))


def ply():
    tet_v = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
    tet_f = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    ascii_ply = ("ply\nformat ascii 1.0\ncomment SPACE=LPS\nelement vertex 4\nproperty float x\n"
                 "property float y\nproperty float z\nelement face 4\n"
                 "property list uchar int vertex_indices\nend_header\n")
    ascii_ply += "".join("%g %g %g\n" % v for v in tet_v)
    ascii_ply += "".join("3 %d %d %d\n" % f for f in tet_f)
    put("fuzz_ply", "ascii", ascii_ply)
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\n"
            "property float y\nproperty float z\nproperty uchar stop\nelement face 4\n"
            "property list uchar int vertex_indices\nend_header\n").encode()
    body = b"".join(struct.pack("<3fB", *v, 1) for v in tet_v)
    body += b"".join(struct.pack("<B3i", 3, *f) for f in tet_f)
    put("fuzz_ply", "binary_stop", head + body)
    quad = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty double x\nproperty double y\n"
            "property double z\nelement face 1\nproperty list uchar uint vertex_index\n"
            "end_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n")
    put("fuzz_ply", "quad_double", quad)


def run_config():
    put("fuzz_run_config", "full", """[daemon]
source = "unix:/run/sonomesh/probe.sock"
out = "/var/lib/sonomesh/out"
seed_mm = [1.0, 2.0, 3.5]
queue_capacity = 2
log_level = "info"

[http]
address = "127.0.0.1:8787"
allow_remote = false

[source]
rate_hz = 0.0
max_dims = [1024, 1024, 1024]
max_payload_bytes = 1073741824
record_path = ""
connect_timeout_ms = 1000

[limits]
max_lost_lines = 100000
keep_meshes = 0

[pipeline]
smooth_sigma_mm = "auto"
cell_from_voxel = true
target = "dark"
""")
    put("fuzz_run_config", "sim", '[daemon]\nsource = "sim:sphere?rate=5&size=64"\nout = "o"\n'
        '[pipeline]\nsmooth_sigma_mm = 0.8\ntarget = "auto"\n')
    put("fuzz_run_config", "bad_key", "[daemon]\nsourc = 1\n")
    put("fuzz_run_config", "empty", "")


def seed_body():
    for name, text in [("csv", "1.5,2,-3"), ("spaces", " 1 2 3 \n"), ("array", "[1, 2, 3.25]"),
                       ("object", '{"seed_mm": [10, 20, 30]}'), ("nan", "nan,1,2"),
                       ("extra", "1,2,3,4"), ("nested", '{"seed_mm": {"x": 1}}')]:
        put("fuzz_seed_body", name, text)


def crc64(data):
    """CRC-64 ECMA-182, MSB first, initial value 0: OpenIGTLink's crc64()."""
    crc = 0
    for b in data:
        crc ^= b << 56
        for _ in range(8):
            crc = ((crc << 1) ^ 0x42F0E1EBA9EA3693) if crc & (1 << 63) else crc << 1
            crc &= (1 << 64) - 1
    return crc


def igtl_message(kind, device, body, version=1, stamp=(1700000000 << 32) | (1 << 31)):
    head = struct.pack(">H12s20sQQ", version, kind.encode(), device.encode(), stamp, len(body))
    return head + struct.pack(">Q", crc64(body)) + body


def igtl_v2_body(content, message_id, meta=(("Source", "probe-sim"),)):
    """Version-2 body: extended header, content, metadata header, metadata."""
    meta_head = struct.pack(">H", len(meta))
    meta_data = b""
    for key, value in meta:
        meta_head += struct.pack(">HHI", len(key), 3, len(value))  # 3: US-ASCII
        meta_data += (key + value).encode()
    ext = struct.pack(">HHII", 12, len(meta_head), len(meta_data), message_id)
    return ext + content + meta_head + meta_data


def igtl_image(dims, scalar, endian, coord, spacing=(0.5, 0.5, 1.0), centre=(1.0, 2.0, 3.0)):
    """IMAGE content: 72-byte image header (floats always big endian), then the voxels."""
    columns = [[spacing[c] if a == c else 0.0 for a in range(3)] for c in range(3)]
    head = struct.pack(">HBBBB3H", 1, 1, scalar, endian, coord, *dims)
    head += struct.pack(">12f", *columns[0], *columns[1], *columns[2], *centre)
    head += struct.pack(">6H", 0, 0, 0, *dims)
    n = dims[0] * dims[1] * dims[2]
    if scalar == 3:
        data = bytes(i % 251 for i in range(n))
    else:
        data = struct.pack((">" if endian == 1 else "<") + "%dH" % n, *range(1000, 1000 + n))
    return head + data


def igtl_status(code, name, text):
    return struct.pack(">Hq20s", code, 0, name.encode()) + text.encode() + b"\0"


def igtl():
    # First byte of every input: the chunk size the target feeds with (value + 1).
    u8_be = igtl_image((4, 3, 2), 3, 1, 1)
    u16_be = igtl_image((2, 2, 2), 5, 1, 2)
    u16_le = igtl_image((3, 2, 2), 5, 2, 1, spacing=(0.3, 0.3, 0.6))
    u8_le_lps = igtl_image((2, 3, 4), 3, 2, 2)
    status = igtl_message("STATUS", "Server", igtl_status(1, "OK", "ready"))
    v1 = [igtl_message("IMAGE", "Image_Reference", c) for c in (u8_be, u16_be, u16_le, u8_le_lps)]
    v2 = [igtl_message("IMAGE", "Image_Reference", igtl_v2_body(c, i), version=2)
          for i, c in enumerate((u8_be, u16_le))]
    put("fuzz_igtl", "v1_images", b"\x39" + status + b"".join(v1))
    put("fuzz_igtl", "v2_images", b"\x07" + b"".join(v2))
    put("fuzz_igtl", "v1_uint16_be", b"\xff" + v1[1])
    put("fuzz_igtl", "v2_uint16_le", b"\x00" + v2[1])
    put("fuzz_igtl", "status_v2", b"\x20" + igtl_message(
        "STATUS", "Server", igtl_v2_body(igtl_status(13, "CONFIG", "probe missing"), 9), version=2))
    bad_crc = bytearray(v1[0])
    bad_crc[-1] ^= 0xFF
    put("fuzz_igtl", "bad_crc_then_good", b"\x10" + bytes(bad_crc) + v1[2])
    put("fuzz_igtl", "truncated_body", b"\x05" + v1[0][:100])
    put("fuzz_igtl", "truncated_header", b"\x05" + status + v1[0][:30])
    put("fuzz_igtl", "transform_skip", b"\x3f" + igtl_message(
        "TRANSFORM", "Probe", struct.pack(">12f", 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0)) + v1[0])


if __name__ == "__main__":
    probe_stream()
    nrrd()
    metaimage()
    nifti()
    ply()
    run_config()
    seed_body()
    igtl()
