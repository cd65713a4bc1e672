#pragma once
/// @file
/// @brief `--igtl-listen`: an OpenIGTLink server for 3D Slicer's OpenIGTLinkIF, an output sink.
///
/// Every processed volume becomes one result set (POLYDATA, IMAGE, STRING; igtl_messages.h),
/// packed once on the writer thread and queued to each client (a queue of 2 sets, newest wins,
/// drops counted). One thread serves every client with non-blocking sockets, so a client that
/// stops reading costs the pipeline nothing. A client that connects gets the latest set at once;
/// what a client sends (Slicer's STATUS, GET_ queries) is read and skipped, a GET_ answered with
/// the latest set. A vanished client is noticed by TCP keep-alive or a failed send and dropped.

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "daemon/internal/bounded_queue.h"
#include "daemon/internal/http_status.h"
#include "daemon/internal/output_sink.h"
#include "daemon/internal/run_stats.h"

namespace sonomesh::daemon {

class IgtlServer : public OutputSink {
 public:
  /// Result sets a client may have waiting; an older one is dropped for a newer (DESIGN.md).
  static constexpr std::size_t kClientQueue = 2;

  explicit IgtlServer(RunStats& stats);
  ~IgtlServer() override;
  IgtlServer(const IgtlServer&) = delete;
  IgtlServer& operator=(const IgtlServer&) = delete;

  /// Binds, listens and starts serving. Returns the bound port (address.port 0: any free one).
  /// @throws std::runtime_error naming the address if it cannot be bound.
  int start(const HttpAddress& address);
  void stop() override;

  const char* name() const override { return "igtl"; }
  void on_line(const nlohmann::json& line, const ProcessedVolume* volume) override;

  /// Packs and sends one result set on the calling thread. on_line() instead hands a copy to the
  /// server's packing thread (packing a 128³ set costs ~90 ms: the writer must not wait for it);
  /// a set still waiting to be packed when a newer one comes is dropped (counted).
  void publish(const ProcessedVolume& volume, const std::string& status_line);

 private:
  struct Client;
  struct PackJob {
    ProcessedVolume volume;
    std::string status_line;
  };
  void pack_loop();
  void serve();
  void accept_clients();
  bool read_from(Client& client);
  bool write_to(Client& client);
  void update_stats();

  RunStats& stats_;
  int listen_fd_ = -1;
  int wake_fd_ = -1;  // eventfd: a new set is queued, or stop
  std::thread thread_;
  std::thread packer_;
  BoundedQueue<PackJob> pack_queue_{1, QueueMode::KeepNewest};
  std::atomic<bool> stopping_{false};

  std::mutex mutex_;  // clients_ and latest_: the writer thread queues, the server thread sends
  std::vector<std::shared_ptr<Client>> clients_;
  std::shared_ptr<const std::string> latest_;
  std::uint64_t sets_sent_ = 0;
  std::uint64_t sets_dropped_ = 0;
};

}  // namespace sonomesh::daemon
