// GoogleTest main for the hil suite: re-executes itself under libumockdev-preload when needed, so
// the binary runs directly (ctest, IDE) without umockdev-wrapper (docs/hil-emulation.md).
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

int main(int argc, char** argv) {
  const char* preload = std::getenv("LD_PRELOAD");
  if (!preload || !std::strstr(preload, "libumockdev-preload")) {
    std::string value = "libumockdev-preload.so.0";
    if (preload && *preload) value = std::string(preload) + ":" + value;  // keep e.g. libasan first
    setenv("LD_PRELOAD", value.c_str(), 1);
    execv("/proc/self/exe", argv);
    std::perror("execv(/proc/self/exe)");
    return 127;
  }
  testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
