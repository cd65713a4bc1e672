#pragma once
/// @file
/// @brief Finding and claiming a USB bulk probe with libusb; libusb errors as AcquireError
/// (internal).

#include <libusb.h>

#include <cstdint>
#include <string>
#include <string_view>
#include <tl/expected.hpp>

#include "acquire/acquire.h"

namespace sonomesh::acquire::internal {

struct UsbSpec {
  std::uint16_t vendor_id = 0;
  std::uint16_t product_id = 0;
  std::string serial;        // empty: any
  std::string text() const;  // "vvvv:pppp[/SERIAL]"
};

/// "VID:PID[/SERIAL]" with hex VID and PID.
tl::expected<UsbSpec, AcquireError> parse_usb_spec(std::string_view text);

/// `what: LIBUSB_ERROR_*` with the matching code (NO_DEVICE -> Disconnected, NOT_FOUND ->
/// NotFound, TIMEOUT -> Timeout, else IoError) and errno.
AcquireError usb_error(const std::string& what, int libusb_code);

struct OpenedProbe {
  libusb_device_handle* handle = nullptr;  // interface 0 claimed
  unsigned char endpoint = 0;              // its first bulk IN endpoint
};

/// Enumerates `ctx`, opens the first device matching VID:PID (and serial), finds interface 0's
/// bulk IN endpoint and claims interface 0. On error nothing stays open.
tl::expected<OpenedProbe, AcquireError> open_probe(libusb_context* ctx, const UsbSpec& spec);

}  // namespace sonomesh::acquire::internal
