#include "daemon/internal/volume_queue.h"

#include <stdexcept>

namespace sonomesh::daemon {

VolumeQueue::VolumeQueue(std::size_t capacity, Mode mode) : capacity_(capacity), mode_(mode) {
  if (capacity < 1) throw std::invalid_argument("queue capacity must be at least 1");
}

std::vector<QueuedVolume> VolumeQueue::push(QueuedVolume volume) {
  std::unique_lock lock(mutex_);
  std::vector<QueuedVolume> out;
  if (closed_) {
    out.push_back(std::move(volume));
    return out;
  }
  if (mode_ == Mode::Block) {
    not_full_.wait(lock, [&] { return closed_ || items_.size() < capacity_; });
    if (closed_) {
      out.push_back(std::move(volume));
      return out;
    }
    items_.push_back(std::move(volume));
  } else {
    while (!items_.empty()) {
      out.push_back(std::move(items_.front()));
      items_.pop_front();
    }
    items_.push_back(std::move(volume));
  }
  lock.unlock();
  not_empty_.notify_one();
  return out;
}

std::optional<QueuedVolume> VolumeQueue::pop(std::chrono::milliseconds timeout) {
  std::unique_lock lock(mutex_);
  if (!not_empty_.wait_for(lock, timeout, [&] { return closed_ || !items_.empty(); })) {
    return std::nullopt;
  }
  if (items_.empty()) return std::nullopt;  // closed and drained
  QueuedVolume v = std::move(items_.front());
  items_.pop_front();
  lock.unlock();
  not_full_.notify_one();
  return v;
}

void VolumeQueue::close() {
  {
    std::lock_guard lock(mutex_);
    closed_ = true;
  }
  not_empty_.notify_all();
  not_full_.notify_all();
}

std::vector<QueuedVolume> VolumeQueue::abort() {
  std::vector<QueuedVolume> out;
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

bool VolumeQueue::closed() const {
  std::lock_guard lock(mutex_);
  return closed_;
}

std::size_t VolumeQueue::size() const {
  std::lock_guard lock(mutex_);
  return items_.size();
}

void VolumeQueue::set_capacity(std::size_t capacity) {
  if (capacity < 1) throw std::invalid_argument("queue capacity must be at least 1");
  {
    std::lock_guard lock(mutex_);
    capacity_ = capacity;
  }
  not_full_.notify_all();
}

}  // namespace sonomesh::daemon
