#include "tests/hil/fake_usb_probe.h"

#include <linux/usbdevice_fs.h>
#include <sys/ioctl.h>
#include <umockdev.h>

#include <algorithm>
#include <cerrno>
#include <cstddef>
#include <cstdio>
#include <cstring>
#include <stdexcept>

namespace sonomesh::hil {
namespace {

constexpr int kUrbTypeControl = USBDEVFS_URB_TYPE_CONTROL;
constexpr int kUrbTypeBulk = USBDEVFS_URB_TYPE_BULK;
constexpr int kBulkIn = 0x81;
constexpr std::size_t kBufferOffset = offsetof(usbdevfs_urb, buffer);

std::string hex_upper(const std::vector<std::uint8_t>& bytes) {
  std::string s;
  char tmp[3];
  for (auto b : bytes) {
    std::snprintf(tmp, sizeof tmp, "%02X", b);
    s += tmp;
  }
  return s;
}

std::vector<std::uint8_t> string_descriptor(const std::string& text) {
  std::vector<std::uint8_t> d{static_cast<std::uint8_t>(2 + 2 * text.size()), 3};
  for (char c : text) {
    d.push_back(static_cast<std::uint8_t>(c));
    d.push_back(0);
  }
  return d;
}

UMockdevIoctlData* resolve(UMockdevIoctlData* parent, std::size_t offset, std::size_t len) {
  GError* error = nullptr;
  UMockdevIoctlData* d = umockdev_ioctl_data_resolve(parent, offset, len, &error);
  g_clear_error(&error);
  return d;
}

}  // namespace

// ---------------------------------------------------------------------------------------------

FakeUsbBus::FakeUsbBus() { testbed_ = umockdev_testbed_new(); }

FakeUsbBus::~FakeUsbBus() {
  probes_.clear();
  g_object_unref(testbed_);
}

FakeUsbProbe& FakeUsbBus::add_probe(FakeUsbProbe::Options options) {
  const int devnum = 2 + static_cast<int>(probes_.size());
  probes_.push_back(
      std::unique_ptr<FakeUsbProbe>(new FakeUsbProbe(*this, std::move(options), devnum)));
  return *probes_.back();
}

// ---------------------------------------------------------------------------------------------

FakeUsbProbe::FakeUsbProbe(FakeUsbBus& bus, Options options, int devnum)
    : bus_(bus), options_(std::move(options)), devnum_(devnum) {
  char node[64];
  std::snprintf(node, sizeof node, "/dev/bus/usb/001/%03d", devnum_);
  devnode_ = node;
  syspath_ = "/sys/devices/pci0000:00/0000:00:14.0/usb1/1-" + std::to_string(devnum_ - 1);
  add_device();
  handler_ = umockdev_ioctl_base_new();
  g_signal_connect(handler_, "handle-ioctl", G_CALLBACK(&FakeUsbProbe::on_ioctl), this);
  GError* error = nullptr;
  if (!umockdev_testbed_attach_ioctl(bus_.testbed(), devnode_.c_str(), handler_, &error)) {
    std::string msg = error ? error->message : "unknown";
    g_clear_error(&error);
    throw std::runtime_error("FakeUsbProbe: attach ioctl: " + msg);
  }
}

FakeUsbProbe::~FakeUsbProbe() {
  umockdev_testbed_detach_ioctl(bus_.testbed(), devnode_.c_str(), nullptr);
  g_object_unref(handler_);
  std::lock_guard lock(mutex_);
  for (auto* q : {&in_urbs_, &done_urbs_})
    for (auto& u : *q) g_object_unref(u.data);
}

std::vector<std::uint8_t> FakeUsbProbe::descriptors() const {
  const bool has_serial = !options_.serial.empty();
  std::vector<std::uint8_t> d = {
      // device: USB 2.0, vendor class, ep0 64 bytes, VID, PID, bcdDevice 1.00, strings 1/2/3, 1
      // config
      18, 1, 0x00, 0x02, 0x00, 0x00, 0x00, 64, static_cast<std::uint8_t>(options_.vendor_id & 0xFF),
      static_cast<std::uint8_t>(options_.vendor_id >> 8),
      static_cast<std::uint8_t>(options_.product_id & 0xFF),
      static_cast<std::uint8_t>(options_.product_id >> 8), 0x00, 0x01, 1, 2,
      static_cast<std::uint8_t>(has_serial ? 3 : 0), 1,
      // configuration 1: 32 bytes total, 1 interface, self powered
      9, 2, 32, 0, 1, 1, 0, 0xC0, 50,
      // interface 0: 2 endpoints, vendor specific
      9, 4, 0, 0, 2, 0xFF, 0x00, 0x00, 0,
      // bulk IN 0x81 and bulk OUT 0x01, 512-byte packets (high speed)
      7, 5, kBulkIn, 2, 0x00, 0x02, 0, 7, 5, 0x01, 2, 0x00, 0x02, 0};
  return d;
}

std::string FakeUsbProbe::description() const {
  char ids[64];
  std::snprintf(ids, sizeof ids, "%04x/%x/100", options_.vendor_id, options_.product_id);
  char vid[8], pid[8], dev[16], busdev[32];
  std::snprintf(vid, sizeof vid, "%04x", options_.vendor_id);
  std::snprintf(pid, sizeof pid, "%04x", options_.product_id);
  std::snprintf(dev, sizeof dev, "189:%d", devnum_ - 1);
  std::snprintf(busdev, sizeof busdev, "bus/usb/001/%03d", devnum_);
  const std::string hex = hex_upper(descriptors());
  std::string s = "P: " + syspath_.substr(4) + "\n" +  // without the leading /sys
                  "N: " + busdev + "=" + hex + "\n" + "E: DEVNAME=/dev/" + busdev +
                  "\n"
                  "E: DEVTYPE=usb_device\n"
                  "E: DRIVER=usb\n"
                  "E: SUBSYSTEM=usb\n"
                  "E: PRODUCT=" +
                  ids + "\n" +
                  "E: BUSNUM=001\n"
                  "E: DEVNUM=" +
                  std::string(busdev).substr(std::strlen(busdev) - 3) + "\n" +
                  "E: MAJOR=189\n"
                  "E: MINOR=" +
                  std::to_string(devnum_ - 1) + "\n" +
                  "A: busnum=1\n"
                  "A: devnum=" +
                  std::to_string(devnum_) + "\n" +
                  "A: speed=480\n"
                  "A: bConfigurationValue=1\n"
                  "A: bNumConfigurations=1\n"
                  "A: idVendor=" +
                  vid + "\n" + "A: idProduct=" + pid + "\n" +
                  "A: manufacturer=" + options_.manufacturer + "\n" +
                  "A: product=" + options_.product + "\n";
  if (!options_.serial.empty()) s += "A: serial=" + options_.serial + "\n";
  s += std::string("A: dev=") + dev + "\n" + "H: descriptors=" + hex + "\n";
  return s;
}

void FakeUsbProbe::add_device() {
  GError* error = nullptr;
  if (!umockdev_testbed_add_from_string(bus_.testbed(), description().c_str(), &error)) {
    std::string msg = error ? error->message : "unknown";
    g_clear_error(&error);
    throw std::runtime_error("FakeUsbProbe: add device: " + msg);
  }
}

void FakeUsbProbe::push(const std::vector<std::uint8_t>& bytes) {
  std::lock_guard lock(mutex_);
  if (stream_pos_ > 0 && stream_pos_ == stream_.size()) {
    stream_.clear();
    stream_pos_ = 0;
  }
  stream_.insert(stream_.end(), bytes.begin(), bytes.end());
}

void FakeUsbProbe::set_producer(Producer producer) {
  std::lock_guard lock(mutex_);
  producer_ = std::move(producer);
}

std::uint64_t FakeUsbProbe::bytes_sent() const {
  std::lock_guard lock(mutex_);
  return bytes_sent_;
}

std::size_t FakeUsbProbe::bytes_queued() const {
  std::lock_guard lock(mutex_);
  return available_locked();
}

std::size_t FakeUsbProbe::pending_in_urbs() const {
  std::lock_guard lock(mutex_);
  return in_urbs_.size();
}

bool FakeUsbProbe::plugged() const {
  std::lock_guard lock(mutex_);
  return plugged_;
}

void FakeUsbProbe::unplug() {
  {
    std::lock_guard lock(mutex_);
    if (!plugged_) return;
    plugged_ = false;
    // Like the kernel on disconnect: in-flight URBs complete with -ENODEV (reapable because we
    // advertise REAP_AFTER_DISCONNECT); new submissions fail.
    for (auto& u : in_urbs_) {
      u.status = -ENODEV;
      done_urbs_.push_back(u);
    }
    in_urbs_.clear();
    stream_.clear();
    stream_pos_ = 0;
  }
  umockdev_testbed_uevent(bus_.testbed(), syspath_.c_str(), "remove");
  umockdev_testbed_remove_device(bus_.testbed(), syspath_.c_str());
}

void FakeUsbProbe::replug() {
  {
    std::lock_guard lock(mutex_);
    if (plugged_) return;
  }
  add_device();
  // Removing the node took the ioctl socket's directory entry with it on some versions;
  // attaching again is harmless when it is still there.
  umockdev_testbed_detach_ioctl(bus_.testbed(), devnode_.c_str(), nullptr);
  GError* error = nullptr;
  if (!umockdev_testbed_attach_ioctl(bus_.testbed(), devnode_.c_str(), handler_, &error)) {
    std::string msg = error ? error->message : "unknown";
    g_clear_error(&error);
    throw std::runtime_error("FakeUsbProbe: re-attach ioctl: " + msg);
  }
  {
    std::lock_guard lock(mutex_);
    plugged_ = true;
  }
  umockdev_testbed_uevent(bus_.testbed(), syspath_.c_str(), "add");
}

int FakeUsbProbe::on_ioctl(UMockdevIoctlBase*, UMockdevIoctlClient* client, void* self) {
  return static_cast<FakeUsbProbe*>(self)->handle_ioctl(client) ? TRUE : FALSE;
}

bool FakeUsbProbe::fill_control(Urb& urb) {
  // Setup packet = first 8 bytes of the buffer; data stage follows it.
  UMockdevIoctlData* buf =
      resolve(urb.data, kBufferOffset, static_cast<std::size_t>(urb.buffer_length));
  if (!buf || urb.buffer_length < 8) {
    urb.status = -EINVAL;
    return false;
  }
  const std::uint8_t* setup = buf->data;
  const int request_type = setup[0];
  const int request = setup[1];
  const int value = setup[2] | (setup[3] << 8);
  const int length = setup[6] | (setup[7] << 8);
  std::vector<std::uint8_t> reply;
  bool ok = false;
  if (request_type == 0x80 && request == 6 /* GET_DESCRIPTOR */) {
    const int type = value >> 8;
    const int index = value & 0xFF;
    const auto all = descriptors();
    if (type == 1) {
      reply.assign(all.begin(), all.begin() + 18);
      ok = true;
    } else if (type == 2 && index == 0) {
      reply.assign(all.begin() + 18, all.end());
      ok = true;
    } else if (type == 3) {
      ok = true;
      if (index == 0)
        reply = {4, 3, 0x09, 0x04};  // LANGID en-US
      else if (index == 1)
        reply = string_descriptor(options_.manufacturer);
      else if (index == 2)
        reply = string_descriptor(options_.product);
      else if (index == 3 && !options_.serial.empty())
        reply = string_descriptor(options_.serial);
      else
        ok = false;
    }
  }
  if (!ok) {
    urb.status = -EPIPE;  // stall
    return false;
  }
  const std::size_t n = std::min<std::size_t>({reply.size(), static_cast<std::size_t>(length),
                                               static_cast<std::size_t>(urb.buffer_length - 8)});
  std::memcpy(buf->data + 8, reply.data(), n);
  auto* u = reinterpret_cast<usbdevfs_urb*>(urb.data->data);
  u->actual_length = static_cast<int>(n);
  u->status = 0;
  return true;
}

void FakeUsbProbe::complete_reap(UMockdevIoctlClient* client, UMockdevIoctlData* slot, Urb urb) {
  umockdev_ioctl_data_set_ptr(slot, 0, urb.data);
  umockdev_ioctl_client_complete(client, 0, 0);
  g_object_unref(urb.data);  // the reap argument holds its own reference now
  g_object_unref(slot);
}

bool FakeUsbProbe::handle_ioctl(UMockdevIoctlClient* client) {
  const unsigned long request = umockdev_ioctl_client_get_request(client);
  UMockdevIoctlData* arg = umockdev_ioctl_client_get_arg(client);
  std::unique_lock lock(mutex_);

  switch (request) {
    case USBDEVFS_GET_CAPABILITIES: {
      UMockdevIoctlData* d = resolve(arg, 0, sizeof(std::uint32_t));
      if (!d) break;
      const std::uint32_t caps = USBDEVFS_CAP_BULK_SCATTER_GATHER | USBDEVFS_CAP_BULK_CONTINUATION |
                                 USBDEVFS_CAP_NO_PACKET_SIZE_LIM |
                                 USBDEVFS_CAP_REAP_AFTER_DISCONNECT | USBDEVFS_CAP_ZERO_PACKET;
      std::memcpy(d->data, &caps, sizeof caps);
      umockdev_ioctl_client_complete(client, 0, 0);
      g_object_unref(d);
      return true;
    }
    case USBDEVFS_CLAIMINTERFACE:
    case USBDEVFS_RELEASEINTERFACE:
    case USBDEVFS_SETINTERFACE:
    case USBDEVFS_SETCONFIGURATION:
    case USBDEVFS_CLEAR_HALT:
    case USBDEVFS_RESET:
    case USBDEVFS_RESETEP:
    case USBDEVFS_DISCONNECT_CLAIM:
      if (!plugged_)
        umockdev_ioctl_client_complete(client, -1, ENODEV);
      else
        umockdev_ioctl_client_complete(client, 0, 0);
      return true;
    case USBDEVFS_GETDRIVER:
    case USBDEVFS_IOCTL:
      umockdev_ioctl_client_complete(client, -1, ENODATA);
      return true;

    case USBDEVFS_SUBMITURB: {
      if (!plugged_) {
        umockdev_ioctl_client_complete(client, -1, ENODEV);
        return true;
      }
      UMockdevIoctlData* d = resolve(arg, 0, sizeof(usbdevfs_urb));
      if (!d) break;
      const auto* u = reinterpret_cast<const usbdevfs_urb*>(d->data);
      Urb urb{d, d->client_addr, u->type, u->endpoint, u->buffer_length, 0};
      // The data buffer is resolved only at reap time, with the length actually delivered:
      // resolving copies client memory both ways, so this halves the bytes moved per URB.
      if (urb.type == kUrbTypeBulk && urb.endpoint == kBulkIn) {
        in_urbs_.push_back(urb);
      } else if (urb.type == kUrbTypeControl) {
        fill_control(urb);
        auto* uu = reinterpret_cast<usbdevfs_urb*>(d->data);
        uu->status = urb.status ? urb.status : uu->status;
        done_urbs_.push_back(urb);
      } else if (urb.type == kUrbTypeBulk && !(urb.endpoint & 0x80)) {
        auto* uu = reinterpret_cast<usbdevfs_urb*>(d->data);
        uu->actual_length = urb.buffer_length;  // OUT data is accepted and ignored
        uu->status = 0;
        done_urbs_.push_back(urb);
      } else {
        g_object_unref(d);
        umockdev_ioctl_client_complete(client, -1, EINVAL);
        return true;
      }
      umockdev_ioctl_client_complete(client, 0, 0);
      return true;
    }

    case USBDEVFS_DISCARDURB: {
      const unsigned long target = *reinterpret_cast<const unsigned long*>(arg->data);
      for (auto it = in_urbs_.begin(); it != in_urbs_.end(); ++it) {
        if (it->client_addr == target) {
          Urb urb = *it;
          in_urbs_.erase(it);
          auto* u = reinterpret_cast<usbdevfs_urb*>(urb.data->data);
          u->status = -ENOENT;
          u->actual_length = 0;
          urb.status = -ENOENT;
          done_urbs_.push_back(urb);
          umockdev_ioctl_client_complete(client, 0, 0);
          return true;
        }
      }
      umockdev_ioctl_client_complete(client, -1, EINVAL);  // already completed
      return true;
    }

    case USBDEVFS_REAPURB:
    case USBDEVFS_REAPURBNDELAY: {
      // The argument points at the caller's `void*` slot that receives the URB's address.
      UMockdevIoctlData* reap_arg = resolve(arg, 0, sizeof(void*));
      if (!reap_arg) break;
      if (!done_urbs_.empty()) {
        Urb urb = done_urbs_.front();
        done_urbs_.pop_front();
        if (urb.status != 0) {
          auto* u = reinterpret_cast<usbdevfs_urb*>(urb.data->data);
          u->status = urb.status;
          u->actual_length = 0;
        }
        lock.unlock();
        complete_reap(client, reap_arg, urb);
        return true;
      }
      if (!plugged_) {
        lock.unlock();
        g_object_unref(reap_arg);
        umockdev_ioctl_client_complete(client, -1, ENODEV);
        return true;
      }
      if (!in_urbs_.empty() && available_locked() == 0 && producer_) {
        std::vector<std::uint8_t> more;
        producer_(more);
        if (stream_pos_ == stream_.size()) {
          stream_.clear();
          stream_pos_ = 0;
        }
        stream_.insert(stream_.end(), more.begin(), more.end());
      }
      if (!in_urbs_.empty() && available_locked() > 0) {
        Urb urb = in_urbs_.front();
        in_urbs_.pop_front();
        const std::size_t n =
            std::min<std::size_t>(available_locked(), static_cast<std::size_t>(urb.buffer_length));
        UMockdevIoctlData* buf = resolve(urb.data, kBufferOffset, n);
        auto* u = reinterpret_cast<usbdevfs_urb*>(urb.data->data);
        if (buf) {
          std::memcpy(buf->data, stream_.data() + stream_pos_, n);
          stream_pos_ += n;
          bytes_sent_ += n;
          u->actual_length = static_cast<int>(n);
          u->status = 0;
        } else {
          u->actual_length = 0;
          u->status = -EFAULT;
        }
        lock.unlock();
        complete_reap(client, reap_arg, urb);
        return true;
      }
      lock.unlock();
      g_object_unref(reap_arg);
      umockdev_ioctl_client_complete(client, -1, EAGAIN);
      return true;
    }
    default:
      break;
  }
  umockdev_ioctl_client_complete(client, -1, request == USBDEVFS_SUBMITURB ? EFAULT : ENOTTY);
  return true;
}

}  // namespace sonomesh::hil
