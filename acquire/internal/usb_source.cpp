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
#include <utility>
#include <vector>

#include "acquire/acquire.h"
#include "acquire/internal/backoff.h"
#include "acquire/internal/sources.h"
#include "acquire/internal/stream_decoder.h"
#include "acquire/internal/usb_probe.h"
#include "acquire/internal/waker.h"

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

AcquireError make_error(AcquireError::Code code, std::string detail, int os_errno = 0) {
  return AcquireError{code, os_errno, std::move(detail), {}, 0};
}

class UsbSource final : public Source {
 public:
  UsbSource(UsbSpec spec, const SourceOptions& options)
      : spec_(std::move(spec)), decoder_(options) {}

  ~UsbSource() override { teardown(); }

  UsbSource(const UsbSource&) = delete;
  UsbSource& operator=(const UsbSource&) = delete;

  tl::expected<void, AcquireError> start() { return connect(); }

  Result next(std::chrono::milliseconds timeout) override {
    const auto deadline = Clock::now() + timeout;
    for (;;) {
      if (!ready_.empty()) {
        Result r = std::move(ready_.front());
        ready_.pop_front();
        return r;
      }
      if (std::exchange(woken_, false) || waker_.drain()) return timeout_error();
      const auto now = Clock::now();
      if (!connected_) {
        if (backoff_.due()) {
          if (connect()) {
            backoff_.succeeded();
            continue;
          }
          backoff_.failed();
        }
        if (Clock::now() >= deadline) return timeout_error();
        woken_ = waker_.sleep_until(std::min(backoff_.next_attempt(), deadline));
        continue;
      }
      if (now >= deadline) return timeout_error();
      pump(deadline);
    }
  }

  std::string describe() const override { return "usb:" + spec_.text(); }
  bool live() const override { return true; }

  void interrupt() override {
    waker_.wake();  // sticky: the next next() returns Timeout even if none is blocked now
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
      woken_ = waker_.sleep_until(std::min(
          deadline, Clock::now() + std::chrono::duration_cast<Clock::duration>(kIdleBackoff)));
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
    ready_.push_back(
        tl::unexpected(make_error(AcquireError::Code::Disconnected,
                                  "usb:" + spec_.text() + ": device disconnected" +
                                      (lost_detail_.empty() ? "" : " (" + lost_detail_ + ")"),
                                  ENODEV)));
    lost_detail_.clear();
    backoff_.dropped();
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
        ready_.push_back(
            tl::unexpected(make_error(AcquireError::Code::IoError,
                                      "usb:" + spec_.text() + ": bulk IN transfer failed (status " +
                                          std::to_string(t->status) + ")",
                                      EIO)));
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
    const int r = libusb_init(&ctx);
    if (r != 0) return tl::unexpected(usb_error("usb: libusb_init", r));
    {
      std::lock_guard lock(ctx_mutex_);
      ctx_ = ctx;
    }
    auto fail = [&](AcquireError e) -> tl::expected<void, AcquireError> {
      teardown();
      return tl::unexpected(std::move(e));
    };

    auto probe = open_probe(ctx_, spec_);
    if (!probe) return fail(probe.error());
    handle_ = probe->handle;
    endpoint_ = probe->endpoint;
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
      if (!slot->transfer)
        return fail(make_error(AcquireError::Code::IoError, "usb: out of memory", ENOMEM));
      libusb_fill_bulk_transfer(slot->transfer, handle_, endpoint_, slot->buffer.data(),
                                kTransferBytes, &UsbSource::on_transfer, slot.get(), 0);
      slots_.push_back(std::move(slot));
      submit(*slots_.back());
      if (link_lost_)
        return fail(make_error(AcquireError::Code::IoError,
                               "usb:" + spec_.text() + ": " + lost_detail_, EIO));
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
  Waker waker_;
  bool woken_ = false;    // a sleep consumed an interrupt(): next() returns Timeout
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
  Backoff backoff_;
};

}  // namespace

OpenResult open_usb_source(const SourceUri& uri, const SourceOptions& options) {
  if (auto refused = refuse_unknown_keys(uri, {})) return tl::unexpected(*refused);
  auto parsed = parse_usb_spec(uri.body);
  if (!parsed) return tl::unexpected(parsed.error());
  auto source = std::make_unique<UsbSource>(std::move(*parsed), options);
  if (auto started = source->start(); !started) return tl::unexpected(started.error());
  return source;
}

}  // namespace sonomesh::acquire::internal
