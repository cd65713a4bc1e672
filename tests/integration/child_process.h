#pragma once
/// @file
/// @brief Child processes and scratch directories for the tests that run sonomeshd / probe-sim as
/// separate processes: one scratch directory, one child process (its own environment and extra
/// descriptors if asked), JSON-lines files read back, polling with a deadline.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

extern char** environ;

namespace sonomesh::testing {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

// A scratch directory, removed at the end of a test that passed (kept for inspection otherwise).
class ScratchDir {
 public:
  explicit ScratchDir(const std::string& name)
      // Short: unix socket paths are limited to 107 bytes.
      : path_(fs::path("/tmp") / ("smi_" + name + "_" + std::to_string(::getpid()))) {
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~ScratchDir() {
    if (!::testing::Test::HasFailure()) {
      std::error_code ec;
      fs::remove_all(path_, ec);
    }
  }
  operator const fs::path&() const { return path_; }
  const fs::path& path() const { return path_; }
  fs::path operator/(const std::string& part) const { return path_ / part; }

 private:
  fs::path path_;
};

// A child process with stdout/stderr in files, extra environment variables and descriptors mapped
// in (child fd -> parent fd); killed (SIGKILL) if still running at destruction.
class Child {
 public:
  Child(const std::vector<std::string>& argv, const fs::path& log_prefix,
        const std::vector<std::string>& extra_env = {},
        const std::vector<std::pair<int, int>>& fds = {}) {
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    const std::string out = log_prefix.string() + ".out";
    err_path_ = log_prefix.string() + ".err";
    posix_spawn_file_actions_addopen(&actions, 1, out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_addopen(&actions, 2, err_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC,
                                     0644);
    for (const auto& [child_fd, parent_fd] : fds)
      posix_spawn_file_actions_adddup2(&actions, parent_fd, child_fd);
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    std::vector<std::string> env_text(extra_env);
    for (char** e = environ; *e; ++e) env_text.emplace_back(*e);
    std::vector<char*> env;
    for (auto& e : env_text) env.push_back(e.data());
    env.push_back(nullptr);
    // The test runner may have signals blocked or ignored; the child must start with defaults.
    posix_spawnattr_t attr;
    posix_spawnattr_init(&attr);
    sigset_t none, all;
    sigemptyset(&none);
    sigfillset(&all);
    posix_spawnattr_setsigmask(&attr, &none);
    posix_spawnattr_setsigdefault(&attr, &all);
    posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETSIGMASK | POSIX_SPAWN_SETSIGDEF);
    if (posix_spawn(&pid_, args[0], &actions, &attr, args.data(), env.data()) != 0) pid_ = -1;
    posix_spawn_file_actions_destroy(&actions);
    posix_spawnattr_destroy(&attr);
  }
  ~Child() {
    if (pid_ > 0 && !exited_) {
      ::kill(pid_, SIGKILL);
      int status;
      ::waitpid(pid_, &status, 0);
    }
  }
  pid_t pid() const { return pid_; }
  void signal(int sig) { ::kill(pid_, sig); }
  // Exit code, or -signal, or nullopt if still running after `timeout`.
  std::optional<int> wait(std::chrono::milliseconds timeout) {
    if (exited_) return code_;
    const auto deadline = Clock::now() + timeout;
    while (true) {
      int status = 0;
      const pid_t r = ::waitpid(pid_, &status, WNOHANG);
      if (r == pid_) {
        exited_ = true;
        code_ = WIFEXITED(status) ? WEXITSTATUS(status) : -WTERMSIG(status);
        return code_;
      }
      if (Clock::now() > deadline) return std::nullopt;
      std::this_thread::sleep_for(20ms);
    }
  }
  bool running() {
    if (exited_) return false;
    return !wait(0ms).has_value();
  }
  std::string stderr_text() const {
    std::ifstream in(err_path_);
    return std::string((std::istreambuf_iterator<char>(in)), {});
  }
  // Resident set size in kB from /proc (0 if gone).
  long rss_kb() const {
    std::ifstream in("/proc/" + std::to_string(pid_) + "/status");
    std::string line;
    while (std::getline(in, line)) {
      if (line.rfind("VmRSS:", 0) == 0) return std::stol(line.substr(6));
    }
    return 0;
  }

 private:
  pid_t pid_ = -1;
  bool exited_ = false;
  int code_ = 0;
  std::string err_path_;
};

// The lines of a JSON-lines file. A last line without its newline is a write in progress and is
// left out; every complete line must parse.
inline std::vector<nlohmann::json> read_jsonl(const fs::path& path) {
  std::vector<nlohmann::json> lines;
  std::ifstream in(path);
  const std::string text((std::istreambuf_iterator<char>(in)), {});
  std::size_t begin = 0;
  for (std::size_t end; (end = text.find('\n', begin)) != std::string::npos; begin = end + 1)
    if (end > begin) lines.push_back(nlohmann::json::parse(text.substr(begin, end - begin)));
  return lines;
}

inline bool wait_until(const std::function<bool()>& ready, std::chrono::milliseconds timeout,
                       std::chrono::milliseconds every = 20ms) {
  const auto deadline = Clock::now() + timeout;
  while (Clock::now() < deadline) {
    if (ready()) return true;
    std::this_thread::sleep_for(every);
  }
  return ready();
}

// The HTTP port a daemon started with --http 127.0.0.1:0 reports in OUT/events.jsonl.
inline int http_port_of(const fs::path& out, std::chrono::milliseconds timeout = 20s) {
  int port = 0;
  wait_until(
      [&] {
        for (const auto& e : read_jsonl(out / "events.jsonl")) {
          if (e.value("event", "") == "http_listening") port = e.value("port", 0);
        }
        return port > 0;
      },
      timeout);
  return port;
}

}  // namespace sonomesh::testing
