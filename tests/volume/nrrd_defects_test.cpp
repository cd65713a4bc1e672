// Regressions for the NRRD reader's defects (issue 19): header lines and paths long enough to
// overflow Teem's message buffer, Teem's leaking error paths, and the payloads read here.
#include <gtest/gtest.h>
#include <malloc.h>
#include <unistd.h>
#include <zlib.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "tests/temp_dir.h"
#include "volume/volume.h"

using namespace sonomesh::volume;
namespace fs = std::filesystem;
using Code = VolumeIoError::Code;

using sonomesh::testing::TempDir;

namespace {

void write_file(const fs::path& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

const std::string kFields = "type: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n";

void expect_refused(const fs::path& path, Code code) {
  const auto r = read_volume(path);
  ASSERT_FALSE(r) << path << " was read";
  EXPECT_EQ(static_cast<int>(r.error->code), static_cast<int>(code)) << r.error->message;
  EXPECT_NE(r.error->message.find(path.filename().string()), std::string::npos);
  EXPECT_EQ(r.error->message.find('\n'), std::string::npos);
}

std::size_t heap_in_use() { return mallinfo2().uordblks; }

}  // namespace

// The minimal input from issue 19 (printf 'NRRD0004\n%03000d\n\n' 0) used to abort the process.
TEST(NrrdDefects, OverlongHeaderLineIsRefusedBeforeTeem) {
  TempDir dir;
  for (std::size_t length : {1000u, 3000u, 100000u}) {
    const auto attached = dir.path / "long.nrrd";
    write_file(attached, "NRRD0004\n" + std::string(length, '0') + "\n\n");
    expect_refused(attached, Code::BadHeader);
    const auto field = dir.path / "field.nrrd";
    write_file(field,
               "NRRD0004\n" + kFields + "units: " + std::string(length, 'x') + "\n\n12345678");
    expect_refused(field, Code::BadHeader);
    const auto detached = dir.path / "long.nhdr";
    write_file(dir.path / "long.raw", "12345678");
    write_file(detached, "NRRD0004\n" + kFields + "space directions: " + std::string(length, '(') +
                             "\ndata file: long.raw\n");
    expect_refused(detached, Code::BadHeader);
  }
}

// Teem ends a header line at a carriage return as well: a long field line after one, behind a
// key:=value (exempt from the bound), is refused before Teem quotes it (found by fuzz_nrrd,
// which crashed Teem's error message buffer).
TEST(NrrdDefects, AFieldLineAfterACarriageReturnIsBoundedToo) {
  TempDir dir;
  const auto path = dir.path / "cr.nrrd";
  write_file(path, "NRRD0004\nkey:=value\r" + std::string(1000, '0') + ": uint8\n" + kFields +
                       "\n12345678");
  expect_refused(path, Code::BadHeader);
  const auto ok = dir.path / "crlf.nrrd";
  write_file(ok, "NRRD0004\r\nkey:=value\r\n" + kFields + "\n12345678");
  const auto r = read_volume(ok);
  ASSERT_TRUE(r) << r.error->message;
}

// Comments and key:=value lines are never quoted by Teem: 3D Slicer writes ones over 1 KB.
TEST(NrrdDefects, LongCommentsAndKeyValuesStillRead) {
  TempDir dir;
  const auto path = dir.path / "slicer.nrrd";
  write_file(path, "NRRD0004\n# " + std::string(5000, 'c') + "\n" + kFields +
                       "Segmentation_ConversionParameters:=" + std::string(5000, 'p') +
                       "\n\n12345678");
  const auto r = read_volume(path);
  ASSERT_TRUE(r) << r.error->message;
  EXPECT_EQ(r.volume.value(1, 1, 1), '8');
}

// The header is read a block at a time (not as one zeroed 1 MiB buffer per file): the blank line
// after many short lines is still found, and a header over 1 MiB is still refused.
TEST(NrrdDefects, HeaderAcrossReadBlocksAndHeaderLimit) {
  TempDir dir;
  std::string comments;  // the blank line ~10 KiB into the file
  for (int i = 0; i < 1000; ++i) comments += "# c\n";
  const auto many = dir.path / "many.nrrd";
  write_file(many, "NRRD0004\n" + comments + kFields + "\n12345678");
  const auto r = read_volume(many);
  ASSERT_TRUE(r) << r.error->message;
  EXPECT_EQ(r.volume.value(1, 1, 1), '8');

  const auto huge = dir.path / "huge.nrrd";
  write_file(huge, "NRRD0004\n" + kFields + "# " + std::string(std::size_t{1} << 20, 'c'));
  expect_refused(huge, Code::BadHeader);
  EXPECT_NE(read_volume(huge).error->message.find("longer than 1 MiB"), std::string::npos);
}

// A file path of ~1000 bytes ended up in Teem's messages just like a long line.
TEST(NrrdDefects, LongPathsGetCleanErrors) {
  TempDir dir;
  fs::path deep = dir.path;
  for (int level = 0; level < 6; ++level) deep /= std::string(200, static_cast<char>('a' + level));
  fs::create_directories(deep);
  ASSERT_GT(deep.string().size(), 1200u);
  write_file(deep / "bad.nrrd", "NRRD0004\n" + kFields + "foo: bar\n\n12345678");
  expect_refused(deep / "bad.nrrd", Code::BadHeader);
  write_file(deep / "good.nrrd", "NRRD0004\n" + kFields + "\n12345678");
  const auto r = read_volume(deep / "good.nrrd");
  ASSERT_TRUE(r) << r.error->message;
  write_file(deep / "data.raw", "1234");
  write_file(deep / "short.nhdr", "NRRD0004\n" + kFields + "data file: data.raw\n");
  expect_refused(deep / "short.nhdr", Code::TruncatedData);
}

TEST(NrrdDefects, OnlyRealMagicLinesReachTeem) {
  TempDir dir;
  const auto path = dir.path / "magic.nrrd";
  for (const char* magic :
       {"NRRD000X", "NRRD0009", "NRRD000", "NRRD00045", "NRRD0004 ", "3RRD0004"}) {
    write_file(path, std::string(magic) + "\n" + kFields + "\n12345678");
    expect_refused(path, Code::UnknownFormat);
  }
}

// Teem's gzip reader leaked ~23 KB of stream state per corrupt file, its plain-text reader (bad
// magic) 4 KB. The heap must not grow with the number of bad reads. (Under ASan mallinfo2 reports
// nothing; LeakSanitizer checks the same paths there.)
TEST(NrrdDefects, BadFilesDoNotLeak) {
  TempDir dir;
  const auto gz = dir.path / "badgzip.nrrd";
  write_file(gz,
             "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 20 20 20\nencoding: gzip\n\n"
             "\x1f\x8b\x08" +
                 std::string(60, 'x'));
  const auto magic = dir.path / "magic.nrrd";
  write_file(magic,
             "3RRD0004\ntype: short\ndimension: 3\nsizes: 4 4 4\n\n" + std::string(128, '\0'));
  const auto field = dir.path / "field.nrrd";
  write_file(field, "NRRD0004\n" + kFields + "sizes: 2 2\n\n12345678");
  for (const auto& p : {gz, magic, field}) ASSERT_FALSE(read_volume(p));  // warm up Teem's statics
  const std::size_t before = heap_in_use();
  for (int round = 0; round < 200; ++round)
    for (const auto& p : {gz, magic, field}) ASSERT_FALSE(read_volume(p));
  const std::size_t after = heap_in_use();
  EXPECT_LT(after, before + 64 * 1024) << "heap grew from " << before << " to " << after;
}

TEST(NrrdDefects, PayloadsReadHereMatchTeemsLayouts) {
  TempDir dir;
  // Big-endian shorts: swapped here, converted to float.
  const auto be = dir.path / "be.nrrd";
  write_file(be, std::string("NRRD0004\ntype: short\ndimension: 3\nsizes: 2 1 1\nendian: big\n"
                             "encoding: raw\n\n") +
                     std::string("\x01\x02\xff\xfe", 4));
  auto r = read_volume(be);
  ASSERT_TRUE(r) << r.error->message;
  EXPECT_EQ(r.volume.value(0, 0, 0), 258.0f);
  EXPECT_EQ(r.volume.value(1, 0, 0), -2.0f);
  // Gzip: a stream shorter or longer than the header says is refused.
  const std::string raw(8, '\x05');
  std::string packed(64, '\0');
  z_stream zs{};
  deflateInit2(&zs, 6, Z_DEFLATED, 15 + 16, 8, Z_DEFAULT_STRATEGY);
  zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(raw.data()));
  zs.avail_in = static_cast<uInt>(raw.size());
  zs.next_out = reinterpret_cast<Bytef*>(packed.data());
  zs.avail_out = static_cast<uInt>(packed.size());
  deflate(&zs, Z_FINISH);
  packed.resize(zs.total_out);
  deflateEnd(&zs);
  const auto gz = dir.path / "gz.nrrd";
  const std::string head = "NRRD0004\ntype: uchar\ndimension: 3\nencoding: gzip\n";
  write_file(gz, head + "sizes: 2 2 2\n\n" + packed);
  r = read_volume(gz);
  ASSERT_TRUE(r) << r.error->message;
  EXPECT_EQ(r.volume.value(1, 1, 1), 5.0f);
  write_file(gz, head + "sizes: 2 2 4\n\n" + packed);
  expect_refused(gz, Code::TruncatedData);
  write_file(gz, head + "sizes: 2 2 1\n\n" + packed);
  expect_refused(gz, Code::SizeMismatch);
  write_file(gz, head + "sizes: 2 2 2\n\n" + packed.substr(0, packed.size() / 2));
  expect_refused(gz, Code::TruncatedData);
}
