#include "daemon/internal/acquisition.h"

#include <spdlog/spdlog.h>

#include <algorithm>

#include "daemon/internal/clock.h"

namespace sonomesh::daemon {

using acquire::AcquireError;
using internal::Clock;
using internal::ms_since;

namespace {

constexpr auto kPollTimeout = std::chrono::milliseconds(200);
constexpr auto kFirstBackoff = std::chrono::milliseconds(50);
constexpr auto kMaxBackoff = std::chrono::milliseconds(500);
// A repeated sequence this close below the highest one seen is a resend (dropped: it already has
// its line); further back, or 0, means the probe restarted its counter (new journal epoch).
constexpr std::uint64_t kResendWindow = 16;

}  // namespace

void record_skipped(RunContext& context, const QueuedVolume& item, const std::string& reason,
                    nlohmann::json extra) {
  if (!extra.is_object()) extra = nlohmann::json::object();
  extra["reason"] = reason;
  extra["received_age_ms"] = ms_since(item.received);
  try {
    context.recorder.record(item.raw.sequence, JournalStatus::Skipped, std::move(extra),
                            item.epoch);
  } catch (const std::exception& e) {
    context.fatal(e.what());
  }
  spdlog::debug("sequence {} skipped ({})", item.raw.sequence, reason);
}

Acquisition::Acquisition(RunContext context, std::unique_ptr<acquire::Source> source,
                         SourceFactory factory, VolumeQueue& queue, bool live)
    : context_(std::move(context)),
      factory_(std::move(factory)),
      queue_(queue),
      source_(std::move(source)),
      reading_(source_.get()),
      live_(live) {
  // A restart on the same out dir goes on where the journal ends (same epoch, same sequences).
  epoch_ = context_.recorder.journal().epoch();
  highest_sequence_ = context_.recorder.journal().highest_before();
  resume_gap_pending_ = live_ && highest_sequence_.has_value();
}

Acquisition::~Acquisition() = default;

std::optional<std::string> Acquisition::describe_source() {
  std::lock_guard lock(mutex_);
  if (!source_) return std::nullopt;
  return source_->describe();
}

void Acquisition::stop() {
  stopping_ = true;
  std::lock_guard lock(mutex_);
  if (source_) source_->interrupt();
  wake_.notify_all();
}

void Acquisition::close_source() {
  std::lock_guard lock(mutex_);
  reading_ = nullptr;
  source_.reset();
}

void Acquisition::sleep_unless_stopped(std::chrono::milliseconds duration) {
  std::unique_lock lock(mutex_);
  wake_.wait_for(lock, duration, [&] { return stopping_.load(); });
}

bool Acquisition::open_source(std::chrono::milliseconds& backoff) {
  auto opened = factory_();
  if (!opened) {
    const std::string error = acquire::to_string(opened.error());
    context_.stats.set_last_error(error);
    if (!outage_started_) {
      outage_started_ = Clock::now();
      spdlog::warn("source {} not available ({}); retrying", context_.config.snapshot().source,
                   error);
      context_.events.event("source_unavailable", {{"error", error}});
    }
    sleep_unless_stopped(backoff);
    backoff = std::min(backoff * 2, kMaxBackoff);
    return false;
  }
  {
    std::lock_guard lock(mutex_);
    source_ = std::move(*opened);
    reading_ = source_.get();
    if (stopping_) source_->interrupt();
  }
  backoff = kFirstBackoff;
  spdlog::info("source {} opened", reading_->describe());
  context_.events.event("source_opened", {{"source", reading_->describe()}});
  return true;
}

void Acquisition::run() {
  auto backoff = kFirstBackoff;
  while (!stopping_) {
    if (!reading_ && !open_source(backoff)) continue;
    auto next = reading_->next(kPollTimeout);
    if (next) {
      const Clock::time_point received =
          next->received == Clock::time_point{} ? Clock::now() : next->received;
      handle_volume(std::move(*next), received);
      continue;
    }
    if (next.error().code == AcquireError::Code::EndOfStream) {
      context_.stats.set_source_state(SourceState::Ended);
      spdlog::info("end of stream from {}; draining", context_.config.snapshot().source);
      context_.events.event("end_of_stream");
      queue_.close();
      return;
    }
    handle_error(next.error());
  }
  // Stopped: whatever is still queued is accounted for as skipped.
  for (const QueuedVolume& item : queue_.abort()) record_skipped(context_, item, "shutdown");
}

bool Acquisition::claim_or_restart(std::uint64_t seq) {
  if (context_.recorder.claim(seq)) return true;
  const bool resend = highest_sequence_ && seq != 0 && seq + kResendWindow > *highest_sequence_;
  if (resend) {
    spdlog::warn("sequence {} received again; dropped (it already has its journal line)", seq);
    context_.events.event("duplicate_sequence", {{"sequence", seq}});
    return false;
  }
  const std::uint64_t from = highest_sequence_.value_or(0);
  epoch_ = context_.recorder.new_epoch();
  spdlog::warn(
      "sequence went back from {} to {}: the probe restarted its counter; journal "
      "epoch {}",
      from, seq, epoch_);
  context_.events.event("sequence_restart", {{"from", from}, {"to", seq}, {"epoch", epoch_}});
  context_.recorder.claim(seq);
  highest_sequence_ = seq;
  return true;
}

void Acquisition::handle_volume(acquire::RawVolume raw, Clock::time_point received) {
  RunStats& stats = context_.stats;
  if (stats.source_state() != SourceState::Connected) {
    stats.set_source_state(SourceState::Connected);
    if (outage_started_) {
      const double outage_ms = ms_since(*outage_started_);
      spdlog::info("source is back after {:.0f} ms", outage_ms);
      context_.events.event("source_reconnected", {{"outage_ms", outage_ms}});
      outage_started_.reset();
    }
  }
  const std::uint64_t seq = raw.sequence;
  if (done_by_earlier_run(seq)) return;
  if (!claim_or_restart(seq)) return;
  highest_sequence_ = std::max(highest_sequence_.value_or(seq), seq);
  for (const QueuedVolume& old : queue_.push(QueuedVolume{std::move(raw), received, epoch_})) {
    if (old.raw.sequence == seq && old.epoch == epoch_ && queue_.closed()) {
      record_skipped(context_, old, "shutdown");
    } else {
      record_skipped(context_, old, "superseded", {{"superseded_by", seq}});
    }
  }
  stats.set_queue_depth(queue_.size(), queue_.capacity());
}

// A restart on an out dir that has a journal. Replay delivers the same sequences again: those
// with a line from the earlier run are dropped (counted, logged once). A live probe went on while
// the daemon was down: the sequences between the journal's last and the first one now received
// get `lost` lines, as a gap reported by the source would.
bool Acquisition::done_by_earlier_run(std::uint64_t seq) {
  const Journal& journal = context_.recorder.journal();
  if (!live_ && journal.written_before(seq)) {
    if (earlier_done_++ == 0) {
      spdlog::info(
          "replay: sequence {} and any others with a journal line from an earlier run are not "
          "processed again",
          seq);
    }
    return true;
  }
  if (!resume_gap_pending_) return false;
  resume_gap_pending_ = false;
  const std::uint64_t last = *journal.highest_before();
  if (seq <= last + 1) return false;  // no gap, or the probe restarted too (a new epoch)
  handle_error(AcquireError{AcquireError::Code::Lost, 0,
                            "not received while the daemon was not running", last + 1,
                            seq - last - 1});
  return false;
}

void Acquisition::handle_error(const AcquireError& error) {
  switch (error.code) {
    case AcquireError::Code::Timeout:
    case AcquireError::Code::EndOfStream:  // handled by run()
      return;
    case AcquireError::Code::Lost: {
      if (error.count > context_.config.snapshot().max_lost_lines) {
        spdlog::warn(
            "sequence jumped by {} from {}: more than max_lost_lines, recorded as an "
            "event only",
            error.count, error.sequence.value_or(0));
        context_.events.event("sequence_jump", {{"first_missing", error.sequence.value_or(0)},
                                                {"count", error.count}});
        return;
      }
      try {
        const std::uint64_t n =
            context_.recorder.record_lost(error.sequence.value_or(0), error.count, "sequence gap");
        if (n > 0) spdlog::warn("{} volume(s) lost upstream from sequence {}", n, *error.sequence);
      } catch (const std::exception& e) {
        context_.fatal(e.what());
      }
      return;
    }
    case AcquireError::Code::BadRecord:
    case AcquireError::Code::Incomplete:
      return handle_bad_record(error);
    case AcquireError::Code::Disconnected:
    case AcquireError::Code::NotFound:
    case AcquireError::Code::IoError:
      return handle_lost_source(error);
    case AcquireError::Code::InvalidArgument:
      context_.fatal("source: " + acquire::to_string(error));
      return;
  }
}

void Acquisition::handle_bad_record(const AcquireError& error) {
  const std::string reason = std::string(acquire::to_string(error.code)) + ": " + error.detail;
  const std::optional<std::uint64_t> seq = error.sequence;
  if (seq && !context_.recorder.claim(*seq)) {
    spdlog::warn("dropped record for sequence {} which already has a line: {}", *seq, reason);
    context_.events.event("duplicate_rejected", {{"sequence", *seq}, {"reason", reason}});
    return;
  }
  if (seq) highest_sequence_ = std::max(highest_sequence_.value_or(*seq), *seq);
  try {
    context_.recorder.record(seq, JournalStatus::Rejected, {{"reason", reason}}, epoch_);
  } catch (const std::exception& e) {
    context_.fatal(e.what());
  }
  context_.stats.set_last_error(reason);
  spdlog::warn("rejected record{}: {}", seq ? " " + std::to_string(*seq) : std::string(), reason);
}

void Acquisition::handle_lost_source(const AcquireError& error) {
  RunStats& stats = context_.stats;
  stats.set_last_error(acquire::to_string(error));
  if (stats.source_state() != SourceState::Reconnecting) {
    stats.set_source_state(SourceState::Reconnecting);
    stats.count_outage();
    outage_started_ = Clock::now();
    spdlog::warn("source lost: {}; reconnecting", acquire::to_string(error));
    context_.events.event("source_lost", {{"error", acquire::to_string(error)}});
  }
  // A disconnected source waits itself before it reconnects; the others would spin.
  if (error.code != AcquireError::Code::Disconnected) {
    sleep_unless_stopped(std::chrono::milliseconds(100));
  }
}

}  // namespace sonomesh::daemon
