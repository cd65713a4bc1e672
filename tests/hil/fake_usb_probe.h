#pragma once
/// @file
/// @brief Emulated USB probes (umockdev testbed + usbfs ioctl handler) fed by test code.
///
/// The code under test uses the real libusb: udev enumeration over the testbed's sysfs,
/// descriptors from sysfs, and URBs submitted/reaped through USBDEVFS_* ioctls that this handler
/// answers. Bulk IN URBs on endpoint 0x81 are filled, at reap time, from the probe's byte stream
/// (what the test pushed, or what a producer callback generates). Construct the bus before the
/// code under test calls libusb_init(); the process must run under libumockdev-preload.

#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

typedef struct _UMockdevTestbed UMockdevTestbed;
typedef struct _UMockdevIoctlBase UMockdevIoctlBase;
typedef struct _UMockdevIoctlClient UMockdevIoctlClient;
typedef struct _UMockdevIoctlData UMockdevIoctlData;

namespace sonomesh::hil {

class FakeUsbBus;

class FakeUsbProbe {
 public:
  struct Options {
    std::uint16_t vendor_id = 0x1209;
    std::uint16_t product_id = 0x0001;
    std::string serial = "SN0001";  // empty: the device has no serial string
    std::string manufacturer = "sonomesh";
    std::string product = "Fake 3D Probe";
  };
  /// Generates more stream bytes when the queued ones run out (runs on the umockdev thread).
  using Producer = std::function<void(std::vector<std::uint8_t>& out)>;

  ~FakeUsbProbe();
  FakeUsbProbe(const FakeUsbProbe&) = delete;
  FakeUsbProbe& operator=(const FakeUsbProbe&) = delete;

  /// Appends bytes to the bulk IN stream.
  void push(const std::vector<std::uint8_t>& bytes);
  void set_producer(Producer producer);
  /// Bytes handed to the host so far / still queued.
  std::uint64_t bytes_sent() const;
  std::size_t bytes_queued() const;
  /// Bulk IN URBs the host has pending right now.
  std::size_t pending_in_urbs() const;

  /// Cable pulled: every pending and later URB fails with ENODEV, the device leaves sysfs and
  /// /dev, and a "remove" uevent goes out. Queued stream bytes are discarded.
  void unplug();
  /// Plugged back in (same bus address): a fresh device with an empty stream.
  void replug();
  bool plugged() const;

  const Options& options() const { return options_; }
  std::string syspath() const { return syspath_; }
  std::string devnode() const { return devnode_; }

 private:
  friend class FakeUsbBus;
  FakeUsbProbe(FakeUsbBus& bus, Options options, int devnum);

  struct Urb {
    UMockdevIoctlData* data = nullptr;  // the resolved struct usbdevfs_urb (we hold a ref)
    unsigned long client_addr = 0;
    int type = 0;
    int endpoint = 0;
    int buffer_length = 0;
    int status = 0;  // for URBs completed without data (discarded: -ENOENT, unplugged: -ENODEV)
  };

  static int on_ioctl(UMockdevIoctlBase* handler, UMockdevIoctlClient* client, void* self);
  bool handle_ioctl(UMockdevIoctlClient* client);
  void complete_reap(UMockdevIoctlClient* client, UMockdevIoctlData* arg, Urb urb);
  bool fill_control(Urb& urb);
  std::string description() const;
  std::vector<std::uint8_t> descriptors() const;
  void add_device();
  std::size_t available_locked() const { return stream_.size() - stream_pos_; }

  FakeUsbBus& bus_;
  Options options_;
  int devnum_;
  std::string syspath_;
  std::string devnode_;
  UMockdevIoctlBase* handler_ = nullptr;

  mutable std::mutex mutex_;
  bool plugged_ = true;
  std::vector<std::uint8_t> stream_;
  std::size_t stream_pos_ = 0;
  Producer producer_;
  std::uint64_t bytes_sent_ = 0;
  std::deque<Urb> in_urbs_;    // bulk IN, waiting for data
  std::deque<Urb> done_urbs_;  // reapable now (control, OUT, discarded, failed)
};

/// One umockdev testbed with any number of emulated probes on bus 1.
class FakeUsbBus {
 public:
  FakeUsbBus();
  ~FakeUsbBus();
  FakeUsbBus(const FakeUsbBus&) = delete;
  FakeUsbBus& operator=(const FakeUsbBus&) = delete;

  FakeUsbProbe& add_probe(FakeUsbProbe::Options options);
  UMockdevTestbed* testbed() const { return testbed_; }

 private:
  UMockdevTestbed* testbed_ = nullptr;
  std::vector<std::unique_ptr<FakeUsbProbe>> probes_;
};

}  // namespace sonomesh::hil
