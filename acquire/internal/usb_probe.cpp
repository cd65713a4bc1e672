// open_probe(): enumerate, match VID:PID and serial, find the bulk IN endpoint, claim.
#include "acquire/internal/usb_probe.h"

#include <cerrno>
#include <charconv>
#include <cstdio>

namespace sonomesh::acquire::internal {
namespace {

int errno_of(int libusb_code) {
  switch (libusb_code) {
    case LIBUSB_ERROR_IO:
      return EIO;
    case LIBUSB_ERROR_INVALID_PARAM:
      return EINVAL;
    case LIBUSB_ERROR_ACCESS:
      return EACCES;
    case LIBUSB_ERROR_NO_DEVICE:
      return ENODEV;
    case LIBUSB_ERROR_NOT_FOUND:
      return ENOENT;
    case LIBUSB_ERROR_BUSY:
      return EBUSY;
    case LIBUSB_ERROR_TIMEOUT:
      return ETIMEDOUT;
    case LIBUSB_ERROR_OVERFLOW:
      return EOVERFLOW;
    case LIBUSB_ERROR_PIPE:
      return EPIPE;
    case LIBUSB_ERROR_INTERRUPTED:
      return EINTR;
    case LIBUSB_ERROR_NO_MEM:
      return ENOMEM;
    case LIBUSB_ERROR_NOT_SUPPORTED:
      return ENOTSUP;
    default:
      return EIO;
  }
}

AcquireError make_error(AcquireError::Code code, std::string detail, int os_errno = 0) {
  AcquireError e;
  e.code = code;
  e.os_errno = os_errno;
  e.detail = std::move(detail);
  return e;
}

bool parse_hex16(std::string_view s, std::uint16_t& out) {
  if (s.empty() || s.size() > 4) return false;
  unsigned v = 0;
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v, 16);
  if (ec != std::errc{} || ptr != s.data() + s.size()) return false;
  out = static_cast<std::uint16_t>(v);
  return true;
}

}  // namespace

tl::expected<UsbSpec, AcquireError> parse_usb_spec(std::string_view text) {
  UsbSpec spec;
  const auto slash = text.find('/');
  const std::string_view ids = text.substr(0, slash);
  if (slash != std::string_view::npos) spec.serial = std::string(text.substr(slash + 1));
  const auto colon = ids.find(':');
  if (colon == std::string_view::npos || !parse_hex16(ids.substr(0, colon), spec.vendor_id) ||
      !parse_hex16(ids.substr(colon + 1), spec.product_id) ||
      (slash != std::string_view::npos && spec.serial.empty()))
    return tl::unexpected(make_error(
        AcquireError::Code::InvalidArgument,
        "usb:" + std::string(text) + ": expected usb:VID:PID[/SERIAL] with hex VID/PID"));
  return spec;
}

std::string UsbSpec::text() const {
  char buf[16];
  std::snprintf(buf, sizeof buf, "%04x:%04x", vendor_id, product_id);
  return serial.empty() ? std::string(buf) : std::string(buf) + "/" + serial;
}

AcquireError usb_error(const std::string& what, int libusb_code) {
  AcquireError::Code code = AcquireError::Code::IoError;
  if (libusb_code == LIBUSB_ERROR_NO_DEVICE) code = AcquireError::Code::Disconnected;
  if (libusb_code == LIBUSB_ERROR_NOT_FOUND) code = AcquireError::Code::NotFound;
  if (libusb_code == LIBUSB_ERROR_TIMEOUT) code = AcquireError::Code::Timeout;
  return make_error(code, what + ": " + libusb_error_name(libusb_code), errno_of(libusb_code));
}

tl::expected<OpenedProbe, AcquireError> open_probe(libusb_context* ctx, const UsbSpec& spec) {
  libusb_device_handle* handle = nullptr;
  libusb_device_handle* found = nullptr;
  auto fail = [&](AcquireError e) -> tl::expected<OpenedProbe, AcquireError> {
    if (handle) libusb_close(handle);
    return tl::unexpected(std::move(e));
  };
  libusb_device** list = nullptr;
  const ssize_t n = libusb_get_device_list(ctx, &list);
  if (n < 0) return fail(usb_error("usb: enumerate", static_cast<int>(n)));
  std::string serial_seen;
  int open_error = 0;
  for (ssize_t i = 0; i < n && !found; ++i) {
    libusb_device_descriptor desc{};
    if (libusb_get_device_descriptor(list[i], &desc) != 0) continue;
    if (desc.idVendor != spec.vendor_id || desc.idProduct != spec.product_id) continue;
    libusb_device_handle* h = nullptr;
    if (const int o = libusb_open(list[i], &h); o != 0) {
      open_error = o;
      continue;
    }
    if (!spec.serial.empty()) {
      unsigned char text[256] = {};
      const int len = desc.iSerialNumber == 0 ? -1
                                              : libusb_get_string_descriptor_ascii(
                                                    h, desc.iSerialNumber, text, sizeof text - 1);
      const std::string serial =
          len > 0 ? std::string(reinterpret_cast<char*>(text), static_cast<std::size_t>(len)) : "";
      if (serial != spec.serial) {
        if (!serial.empty()) serial_seen += (serial_seen.empty() ? "" : ",") + serial;
        libusb_close(h);
        continue;
      }
    }
    found = h;
  }
  libusb_free_device_list(list, 1);
  if (!found) {
    std::string detail = "usb:" + spec.text() + ": no such device";
    if (!serial_seen.empty()) detail += " (serials present: " + serial_seen + ")";
    if (open_error != 0) return fail(usb_error("usb:" + spec.text() + ": open", open_error));
    return fail(make_error(AcquireError::Code::NotFound, detail, ENODEV));
  }

  libusb_config_descriptor* config = nullptr;
  handle = found;
  int r = libusb_get_active_config_descriptor(libusb_get_device(handle), &config);
  if (r != 0) return fail(usb_error("usb:" + spec.text() + ": config descriptor", r));
  int endpoint = -1;
  for (int i = 0; i < config->bNumInterfaces && endpoint < 0; ++i) {
    const libusb_interface& itf = config->interface[i];
    if (itf.num_altsetting < 1 || itf.altsetting[0].bInterfaceNumber != 0) continue;
    const libusb_interface_descriptor& alt = itf.altsetting[0];
    for (int e = 0; e < alt.bNumEndpoints; ++e) {
      const libusb_endpoint_descriptor& ep = alt.endpoint[e];
      if ((ep.bmAttributes & 0x3) == LIBUSB_TRANSFER_TYPE_BULK &&
          (ep.bEndpointAddress & LIBUSB_ENDPOINT_IN)) {
        endpoint = ep.bEndpointAddress;
        break;
      }
    }
  }
  libusb_free_config_descriptor(config);
  if (endpoint < 0)
    return fail(make_error(AcquireError::Code::InvalidArgument,
                           "usb:" + spec.text() + ": interface 0 has no bulk IN endpoint"));

  libusb_set_auto_detach_kernel_driver(handle, 1);  // not supported everywhere: best effort
  r = libusb_claim_interface(handle, 0);
  if (r != 0) return fail(usb_error("usb:" + spec.text() + ": claim interface 0", r));

  return OpenedProbe{handle, static_cast<unsigned char>(endpoint)};
}

}  // namespace sonomesh::acquire::internal
