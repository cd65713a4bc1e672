/// @file
/// @brief USB bulk probes: protocol v1 records over a bulk IN endpoint, via libusb.
///
/// Several large asynchronous bulk IN transfers stay in flight so the device never waits for the
/// host; libusb events run on the thread calling next() (no extra thread, no locking around the
/// decoder). An unplug (LIBUSB_ERROR_NO_DEVICE / transfer status NO_DEVICE) tears the whole libusb
/// context down and reports Disconnected once; later next() calls re-enumerate with a fresh
/// context (backoff 50 ms doubling to 500 ms), so a returning probe is found without relying on
/// hotplug events. libusb errors are translated to AcquireError here and never escape.

#include <libusb.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <charconv>
#include <chrono>
#include <cstring>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include "acquire/acquire.h"
#include "acquire/internal/sources.h"
#include "acquire/internal/stream_decoder.h"

namespace sonomesh::acquire::internal {
namespace {

using Clock = std::chrono::steady_clock;
using Result = tl::expected<RawVolume, AcquireError>;

constexpr int kTransfers = 4;
constexpr int kTransferBytes = 1024 * 1024;
constexpr std::chrono::milliseconds kMaxEventWait{100};  // bounded so interrupt/deadline are seen
// When libusb's poll reports ready without completing anything (usbfs nodes that are always
// "ready", e.g. under emulation), wait this long before asking again instead of spinning.
constexpr std::chrono::microseconds kIdleBackoff{1000};
constexpr std::chrono::milliseconds kFirstBackoff{50};
constexpr std::chrono::milliseconds kMaxBackoff{500};

int errno_of(int libusb_code) {
  switch (libusb_code) {
    case LIBUSB_ERROR_IO: return EIO;
    case LIBUSB_ERROR_INVALID_PARAM: return EINVAL;
    case LIBUSB_ERROR_ACCESS: return EACCES;
    case LIBUSB_ERROR_NO_DEVICE: return ENODEV;
    case LIBUSB_ERROR_NOT_FOUND: return ENOENT;
    case LIBUSB_ERROR_BUSY: return EBUSY;
    case LIBUSB_ERROR_TIMEOUT: return ETIMEDOUT;
    case LIBUSB_ERROR_OVERFLOW: return EOVERFLOW;
    case LIBUSB_ERROR_PIPE: return EPIPE;
    case LIBUSB_ERROR_INTERRUPTED: return EINTR;
    case LIBUSB_ERROR_NO_MEM: return ENOMEM;
    case LIBUSB_ERROR_NOT_SUPPORTED: return ENOTSUP;
    default: return EIO;
  }
}

AcquireError make_error(AcquireError::Code code, std::string detail, int os_errno = 0) {
  AcquireError e;
  e.code = code;
  e.os_errno = os_errno;
  e.detail = std::move(detail);
  return e;
}

AcquireError usb_error(const std::string& what, int libusb_code) {
  AcquireError::Code code = AcquireError::Code::IoError;
  if (libusb_code == LIBUSB_ERROR_NO_DEVICE) code = AcquireError::Code::Disconnected;
  if (libusb_code == LIBUSB_ERROR_NOT_FOUND) code = AcquireError::Code::NotFound;
  if (libusb_code == LIBUSB_ERROR_TIMEOUT) code = AcquireError::Code::Timeout;
  return make_error(code, what + ": " + libusb_error_name(libusb_code), errno_of(libusb_code));
}

struct UsbSpec {
  std::uint16_t vendor_id = 0;
  std::uint16_t product_id = 0;
  std::string serial;  // empty: any

  std::string text() const {
    char buf[16];
    std::snprintf(buf, sizeof buf, "%04x:%04x", vendor_id, product_id);
    return serial.empty() ? std::string(buf) : std::string(buf) + "/" + serial;
  }
};

bool parse_hex16(std::string_view s, std::uint16_t& out) {
  if (s.empty() || s.size() > 4) return false;
  unsigned v = 0;
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v, 16);
  if (ec != std::errc{} || ptr != s.data() + s.size()) return false;
  out = static_cast<std::uint16_t>(v);
  return true;
}

tl::expected<UsbSpec, AcquireError> parse_spec(std::string_view text) {
  UsbSpec spec;
  const auto slash = text.find('/');
  const std::string_view ids = text.substr(0, slash);
  if (slash != std::string_view::npos) spec.serial = std::string(text.substr(slash + 1));
  const auto colon = ids.find(':');
  if (colon == std::string_view::npos || !parse_hex16(ids.substr(0, colon), spec.vendor_id) ||
      !parse_hex16(ids.substr(colon + 1), spec.product_id) ||
      (slash != std::string_view::npos && spec.serial.empty()))
    return tl::unexpected(make_error(AcquireError::Code::InvalidArgument,
                                     "usb:" + std::string(text) + ": expected usb:VID:PID[/SERIAL] with hex VID/PID"));
  return spec;
}

class UsbSource final : public Source {
 public:
  UsbSource(UsbSpec spec, const SourceOptions& options) : spec_(std::move(spec)), decoder_(options) {}

  ~UsbSource() override {
    teardown();
    if (wake_fd_ >= 0) ::close(wake_fd_);
  }

  UsbSource(const UsbSource&) = delete;
  UsbSource& operator=(const UsbSource&) = delete;

  tl::expected<void, AcquireError> start() {
    wake_fd_ = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (wake_fd_ < 0)
      return tl::unexpected(make_error(AcquireError::Code::IoError, std::string("usb: eventfd: ") + std::strerror(errno), errno));
    return connect();
  }

  Result next(std::chrono::milliseconds timeout) override {
    const auto deadline = Clock::now() + timeout;
    for (;;) {
      if (!ready_.empty()) {
        Result r = std::move(ready_.front());
        ready_.pop_front();
        return r;
      }
      if (interrupted_.exchange(false)) return timeout_error();
      const auto now = Clock::now();
      if (!connected_) {
        if (now >= next_attempt_) {
          if (connect()) {
            backoff_ = kFirstBackoff;
            continue;
          }
          backoff_ = std::min(backoff_ * 2, kMaxBackoff);
          next_attempt_ = Clock::now() + backoff_;
        }
        if (Clock::now() >= deadline) return timeout_error();
        wait_wake(std::min(next_attempt_, deadline));
        continue;
      }
      if (now >= deadline) return timeout_error();
      pump(deadline);
    }
  }

  std::string describe() const override { return "usb:" + spec_.text(); }
  bool live() const override { return true; }

  void interrupt() override {
    interrupted_.store(true);
    const std::uint64_t one = 1;
    [[maybe_unused]] const auto n = ::write(wake_fd_, &one, sizeof one);
    std::lock_guard lock(ctx_mutex_);
    if (ctx_) libusb_interrupt_event_handler(ctx_);
  }

 private:
  struct Slot {
    UsbSource* owner = nullptr;
    libusb_transfer* transfer = nullptr;
    std::vector<unsigned char> buffer;
    bool active = false;
  };

  static Result timeout_error() {
    return tl::unexpected(make_error(AcquireError::Code::Timeout, "no volume within the timeout"));
  }

  void wait_wake(Clock::time_point until) {
    const auto now = Clock::now();
    if (until <= now) return;
    const int ms = static_cast<int>(std::chrono::ceil<std::chrono::milliseconds>(until - now).count());
    pollfd p{wake_fd_, POLLIN, 0};
    if (::poll(&p, 1, ms) > 0) drain_wake();
  }
  void drain_wake() {
    std::uint64_t v;
    while (::read(wake_fd_, &v, sizeof v) > 0) {
    }
  }

  /// One round of libusb event handling, then whatever the decoder has completed.
  void pump(Clock::time_point deadline) {
    const auto start = Clock::now();
    const auto wait = std::min<Clock::duration>(deadline - start, kMaxEventWait);
    const auto us = std::chrono::duration_cast<std::chrono::microseconds>(wait).count();
    timeval tv{static_cast<time_t>(us / 1000000), static_cast<suseconds_t>(us % 1000000)};
    progress_ = false;
    const int r = libusb_handle_events_timeout_completed(ctx_, &tv, nullptr);
    if (r == LIBUSB_ERROR_NO_DEVICE) {
      link_lost_ = true;
    } else if (r < 0 && r != LIBUSB_ERROR_INTERRUPTED && r != LIBUSB_ERROR_TIMEOUT) {
      // A persistently failing event loop would otherwise spin here forever: treat it as a
      // broken link and start over with a fresh context.
      if (++consecutive_errors_ > 16) {
        lost_detail_ = std::string("event handling: ") + libusb_error_name(r);
        link_lost_ = true;
      }
    }
    if (needs_clear_halt_) {
      needs_clear_halt_ = false;
      libusb_clear_halt(handle_, endpoint_);
      for (auto& s : slots_)
        if (!s->active && !link_lost_) submit(*s);
    }
    while (auto result = decoder_.next()) push_result(std::move(*result));
    if (link_lost_) {
      on_link_lost();
      return;
    }
    if (!progress_ && r != LIBUSB_ERROR_INTERRUPTED && Clock::now() - start < kIdleBackoff / 2)
      wait_wake(std::min(deadline, Clock::now() + std::chrono::duration_cast<Clock::duration>(kIdleBackoff)));
  }

  void push_result(Result r) {
    if (r && r->received == Clock::time_point{}) r->received = Clock::now();
    ready_.push_back(std::move(r));
  }

  void on_link_lost() {
    teardown();
    // The record in flight was cut by the unplug: report it, then the outage (once).
    decoder_.end_of_input();
    while (auto result = decoder_.next()) push_result(std::move(*result));
    ready_.push_back(tl::unexpected(make_error(AcquireError::Code::Disconnected,
                                               "usb:" + spec_.text() + ": device disconnected" +
                                                   (lost_detail_.empty() ? "" : " (" + lost_detail_ + ")"),
                                               ENODEV)));
    lost_detail_.clear();
    backoff_ = kFirstBackoff;
    next_attempt_ = Clock::now() + backoff_;
  }

  static void LIBUSB_CALL on_transfer(libusb_transfer* transfer) {
    auto* slot = static_cast<Slot*>(transfer->user_data);
    slot->active = false;
    slot->owner->transfer_done(*slot);
  }

  void transfer_done(Slot& slot) {
    libusb_transfer* t = slot.transfer;
    switch (t->status) {
      case LIBUSB_TRANSFER_COMPLETED:
        consecutive_errors_ = 0;
        if (t->actual_length > 0) {
          decoder_.feed(t->buffer, static_cast<std::size_t>(t->actual_length));
          progress_ = true;
        }
        if (!stopping_) submit(slot);
        return;
      case LIBUSB_TRANSFER_NO_DEVICE:
        link_lost_ = true;
        progress_ = true;
        return;
      case LIBUSB_TRANSFER_CANCELLED:
        return;
      case LIBUSB_TRANSFER_STALL:
        // Clearing a halt is a synchronous control request: not allowed inside a callback.
        needs_clear_halt_ = true;
        progress_ = true;
        return;
      case LIBUSB_TRANSFER_TIMED_OUT:
      case LIBUSB_TRANSFER_ERROR:
      case LIBUSB_TRANSFER_OVERFLOW:
      default:
        progress_ = true;
        if (++consecutive_errors_ > 16) {
          lost_detail_ = "repeated transfer errors";
          link_lost_ = true;
          return;
        }
        ready_.push_back(tl::unexpected(make_error(
            AcquireError::Code::IoError,
            "usb:" + spec_.text() + ": bulk IN transfer failed (status " + std::to_string(t->status) + ")", EIO)));
        if (!stopping_) submit(slot);
        return;
    }
  }

  void submit(Slot& slot) {
    const int r = libusb_submit_transfer(slot.transfer);
    if (r == 0) {
      slot.active = true;
      return;
    }
    lost_detail_ = std::string("submit: ") + libusb_error_name(r);
    link_lost_ = true;
  }

  /// Enumerate, match VID:PID (and serial), open, claim interface 0, start the transfers.
  tl::expected<void, AcquireError> connect() {
    libusb_context* ctx = nullptr;
    int r = libusb_init(&ctx);
    if (r != 0) return tl::unexpected(usb_error("usb: libusb_init", r));
    {
      std::lock_guard lock(ctx_mutex_);
      ctx_ = ctx;
    }
    auto fail = [&](AcquireError e) -> tl::expected<void, AcquireError> {
      teardown();
      return tl::unexpected(std::move(e));
    };

    libusb_device** list = nullptr;
    const ssize_t n = libusb_get_device_list(ctx_, &list);
    if (n < 0) return fail(usb_error("usb: enumerate", static_cast<int>(n)));
    std::string serial_seen;
    int open_error = 0;
    for (ssize_t i = 0; i < n && !handle_; ++i) {
      libusb_device_descriptor desc{};
      if (libusb_get_device_descriptor(list[i], &desc) != 0) continue;
      if (desc.idVendor != spec_.vendor_id || desc.idProduct != spec_.product_id) continue;
      libusb_device_handle* h = nullptr;
      if (const int o = libusb_open(list[i], &h); o != 0) {
        open_error = o;
        continue;
      }
      if (!spec_.serial.empty()) {
        unsigned char text[256] = {};
        const int len = desc.iSerialNumber == 0
                            ? -1
                            : libusb_get_string_descriptor_ascii(h, desc.iSerialNumber, text, sizeof text - 1);
        const std::string serial = len > 0 ? std::string(reinterpret_cast<char*>(text), static_cast<std::size_t>(len)) : "";
        if (serial != spec_.serial) {
          if (!serial.empty()) serial_seen += (serial_seen.empty() ? "" : ",") + serial;
          libusb_close(h);
          continue;
        }
      }
      handle_ = h;
    }
    libusb_free_device_list(list, 1);
    if (!handle_) {
      std::string detail = "usb:" + spec_.text() + ": no such device";
      if (!serial_seen.empty()) detail += " (serials present: " + serial_seen + ")";
      if (open_error != 0) return fail(usb_error("usb:" + spec_.text() + ": open", open_error));
      return fail(make_error(AcquireError::Code::NotFound, detail, ENODEV));
    }

    libusb_config_descriptor* config = nullptr;
    r = libusb_get_active_config_descriptor(libusb_get_device(handle_), &config);
    if (r != 0) return fail(usb_error("usb:" + spec_.text() + ": config descriptor", r));
    int endpoint = -1;
    for (int i = 0; i < config->bNumInterfaces && endpoint < 0; ++i) {
      const libusb_interface& itf = config->interface[i];
      if (itf.num_altsetting < 1 || itf.altsetting[0].bInterfaceNumber != 0) continue;
      const libusb_interface_descriptor& alt = itf.altsetting[0];
      for (int e = 0; e < alt.bNumEndpoints; ++e) {
        const libusb_endpoint_descriptor& ep = alt.endpoint[e];
        if ((ep.bmAttributes & 0x3) == LIBUSB_TRANSFER_TYPE_BULK && (ep.bEndpointAddress & LIBUSB_ENDPOINT_IN)) {
          endpoint = ep.bEndpointAddress;
          break;
        }
      }
    }
    libusb_free_config_descriptor(config);
    if (endpoint < 0)
      return fail(make_error(AcquireError::Code::InvalidArgument,
                             "usb:" + spec_.text() + ": interface 0 has no bulk IN endpoint"));
    endpoint_ = static_cast<unsigned char>(endpoint);

    libusb_set_auto_detach_kernel_driver(handle_, 1);  // not supported everywhere: best effort
    r = libusb_claim_interface(handle_, 0);
    if (r != 0) return fail(usb_error("usb:" + spec_.text() + ": claim interface 0", r));
    claimed_ = true;

    stopping_ = false;
    link_lost_ = false;
    needs_clear_halt_ = false;
    consecutive_errors_ = 0;
    for (int i = 0; i < kTransfers; ++i) {
      auto slot = std::make_unique<Slot>();
      slot->owner = this;
      slot->buffer.resize(kTransferBytes);
      slot->transfer = libusb_alloc_transfer(0);
      if (!slot->transfer) return fail(make_error(AcquireError::Code::IoError, "usb: out of memory", ENOMEM));
      libusb_fill_bulk_transfer(slot->transfer, handle_, endpoint_, slot->buffer.data(), kTransferBytes,
                                &UsbSource::on_transfer, slot.get(), 0);
      slots_.push_back(std::move(slot));
      submit(*slots_.back());
      if (link_lost_) return fail(make_error(AcquireError::Code::IoError, "usb:" + spec_.text() + ": " + lost_detail_, EIO));
    }
    connected_ = true;
    return {};
  }

  /// Cancels the transfers, waits (bounded) for them to come back, closes everything.
  void teardown() {
    connected_ = false;
    stopping_ = true;
    if (ctx_) {
      for (auto& s : slots_)
        if (s->active) libusb_cancel_transfer(s->transfer);
      const auto give_up = Clock::now() + std::chrono::seconds(1);
      while (Clock::now() < give_up &&
             std::any_of(slots_.begin(), slots_.end(), [](const auto& s) { return s->active; })) {
        timeval tv{0, 10000};
        libusb_handle_events_timeout_completed(ctx_, &tv, nullptr);
      }
    }
    bool leaked = false;
    for (auto& s : slots_) {
      if (s->active) {
        // libusb still owns this transfer: freeing it would be a use-after-free; leak it instead.
        leaked = true;
        s.release();
        continue;
      }
      libusb_free_transfer(s->transfer);
    }
    slots_.clear();
    if (handle_) {
      if (claimed_) libusb_release_interface(handle_, 0);
      if (!leaked) libusb_close(handle_);
    }
    claimed_ = false;
    handle_ = nullptr;
    std::lock_guard lock(ctx_mutex_);
    if (ctx_ && !leaked) libusb_exit(ctx_);
    ctx_ = nullptr;
  }

  UsbSpec spec_;
  StreamDecoder decoder_;
  int wake_fd_ = -1;
  std::atomic<bool> interrupted_{false};
  std::mutex ctx_mutex_;  // guards ctx_ against interrupt() from another thread
  libusb_context* ctx_ = nullptr;
  libusb_device_handle* handle_ = nullptr;
  unsigned char endpoint_ = 0;
  bool claimed_ = false;
  bool connected_ = false;
  bool stopping_ = false;
  bool link_lost_ = false;
  bool needs_clear_halt_ = false;
  bool progress_ = false;
  int consecutive_errors_ = 0;
  std::string lost_detail_;
  std::vector<std::unique_ptr<Slot>> slots_;
  std::deque<Result> ready_;
  std::chrono::milliseconds backoff_{kFirstBackoff};
  Clock::time_point next_attempt_{};
};

}  // namespace

tl::expected<std::unique_ptr<Source>, AcquireError> open_usb_source(const std::string& spec,
                                                                    const SourceOptions& options) {
  auto parsed = parse_spec(spec);
  if (!parsed) return tl::unexpected(parsed.error());
  auto source = std::make_unique<UsbSource>(std::move(*parsed), options);
  if (auto started = source->start(); !started) return tl::unexpected(started.error());
  return source;
}

}  // namespace sonomesh::acquire::internal
