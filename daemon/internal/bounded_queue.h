#pragma once
/// @file
/// @brief The daemon's one bounded queue type: between acquisition and worker (volumes), between
/// worker and writer (results), and per OpenIGTLink client (messages).
///
/// KeepNewest never blocks the producer: everything waiting is pushed out by a newer item and
/// handed back so that the caller can account for it (a `skipped` line). DropOldest never blocks
/// either but keeps up to `capacity` items, pushing out the oldest (a dropped-message counter).
/// Block waits for room, so nothing is lost and the producer is held back instead.

#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <deque>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <vector>

namespace sonomesh::daemon {

enum class QueueMode { KeepNewest, DropOldest, Block };

template <typename T>
class BoundedQueue {
 public:
  using Mode = QueueMode;

  /// @throws std::invalid_argument if capacity < 1.
  BoundedQueue(std::size_t capacity, Mode mode) : capacity_(capacity), mode_(mode) {
    if (capacity < 1) throw std::invalid_argument("queue capacity must be at least 1");
  }

  /// KeepNewest, DropOldest: never block; return what they pushed out (oldest first).
  /// Block: waits for room; returns the item itself if the queue was closed or aborted meanwhile.
  std::vector<T> push(T item) {
    std::unique_lock lock(mutex_);
    std::vector<T> out;
    if (mode_ == Mode::Block) {
      not_full_.wait(lock, [&] { return closed_ || items_.size() < capacity_; });
    }
    if (closed_) {
      out.push_back(std::move(item));
      return out;
    }
    const std::size_t keep = mode_ == Mode::KeepNewest ? 0 : capacity_ - 1;
    while (mode_ != Mode::Block && !items_.empty() && items_.size() > keep) {
      out.push_back(std::move(items_.front()));
      items_.pop_front();
    }
    items_.push_back(std::move(item));
    lock.unlock();
    not_empty_.notify_one();
    return out;
  }

  /// Next item, or nothing after `timeout`, or nothing at once when closed and empty.
  std::optional<T> pop(std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    if (!not_empty_.wait_for(lock, timeout, [&] { return closed_ || !items_.empty(); })) {
      return std::nullopt;
    }
    return take(lock);
  }
  /// Next item, waiting as long as it takes; nothing once closed and empty.
  std::optional<T> pop() {
    std::unique_lock lock(mutex_);
    not_empty_.wait(lock, [&] { return closed_ || !items_.empty(); });
    return take(lock);
  }

  /// No more pushes; pop() drains what is queued, then returns nothing (end of stream).
  void close() {
    {
      std::lock_guard lock(mutex_);
      closed_ = true;
    }
    not_empty_.notify_all();
    not_full_.notify_all();
  }
  /// Removes and returns everything still queued and closes the queue (shutdown).
  std::vector<T> abort() {
    std::vector<T> out;
    {
      std::lock_guard lock(mutex_);
      closed_ = true;
      while (!items_.empty()) {
        out.push_back(std::move(items_.front()));
        items_.pop_front();
      }
    }
    not_empty_.notify_all();
    not_full_.notify_all();
    return out;
  }

  bool closed() const {
    std::lock_guard lock(mutex_);
    return closed_;
  }
  std::size_t size() const {
    std::lock_guard lock(mutex_);
    return items_.size();
  }
  std::size_t capacity() const {
    std::lock_guard lock(mutex_);
    return capacity_;
  }
  Mode mode() const { return mode_; }
  /// Changes the capacity (config reload). Items above it stay until popped.
  void set_capacity(std::size_t capacity) {
    if (capacity < 1) throw std::invalid_argument("queue capacity must be at least 1");
    {
      std::lock_guard lock(mutex_);
      capacity_ = capacity;
    }
    not_full_.notify_all();
  }

 private:
  std::optional<T> take(std::unique_lock<std::mutex>& lock) {
    if (items_.empty()) return std::nullopt;  // closed and drained
    T item = std::move(items_.front());
    items_.pop_front();
    lock.unlock();
    not_full_.notify_one();
    return item;
  }

  mutable std::mutex mutex_;
  std::condition_variable not_empty_;
  std::condition_variable not_full_;
  std::deque<T> items_;
  std::size_t capacity_;
  const Mode mode_;
  bool closed_ = false;
};

}  // namespace sonomesh::daemon
