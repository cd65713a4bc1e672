#pragma once
/// @file
/// @brief The writer thread: each processed volume through every sink's write(), then its
/// `processed` line (or `failed`, when an output cannot be written), which the sinks see too.

#include "daemon/internal/acquisition.h"
#include "daemon/internal/worker.h"

namespace sonomesh::daemon {

class Writer {
 public:
  Writer(RunContext context, ResultQueue& in) : context_(std::move(context)), in_(in) {}
  /// Until the worker closes the queue.
  void run();

 private:
  void write_one(WorkerResult& result);

  RunContext context_;
  ResultQueue& in_;
};

}  // namespace sonomesh::daemon
