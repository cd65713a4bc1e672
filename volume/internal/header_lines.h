#pragma once
/// @file
/// @brief A text header's lines, read a block at a time up to a limit: the MetaImage and NRRD
/// readers' one line reader.
///
/// A header is a few hundred bytes; allocating (and zeroing) the whole 1 MiB limit per file made
/// each read cost milliseconds (under ASan, page faults: 32 MetaImage and 93 NRRD reads/s in
/// fuzzing; docs/robustness.md).

#include <algorithm>
#include <cstddef>
#include <istream>
#include <string>

namespace sonomesh::volume::internal {

class HeaderLines {
 public:
  static constexpr std::size_t kMaxHeader = std::size_t{1} << 20;
  explicit HeaderLines(std::istream& in) : in_(in) {}
  /// The next line without its '\n'; false at the end of the file or of kMaxHeader. The last
  /// line may have no '\n' (terminated() says so).
  bool next(std::string& line) {
    for (;;) {
      const std::size_t eol = text_.find('\n', scan_);
      if (eol != std::string::npos) {
        line.assign(text_, pos_, eol - pos_);
        pos_ = scan_ = eol + 1;
        terminated_ = true;
        return true;
      }
      scan_ = text_.size();
      if (!in_ || text_.size() >= kMaxHeader) break;
      const std::size_t old = text_.size(), add = std::min(kBlock, kMaxHeader - old);
      text_.resize(old + add);
      in_.read(text_.data() + old, static_cast<std::streamsize>(add));
      text_.resize(old + static_cast<std::size_t>(in_.gcount()));
    }
    if (pos_ >= text_.size()) return false;
    line.assign(text_, pos_);
    pos_ = scan_ = text_.size();
    terminated_ = false;
    return true;
  }
  /// Bytes up to and including the last line returned.
  std::size_t consumed() const { return pos_; }
  /// The last line returned ended with '\n' (false: at the end of the file or of kMaxHeader).
  bool terminated() const { return terminated_; }
  /// kMaxHeader bytes were read: what follows was not looked at.
  bool at_limit() const { return text_.size() >= kMaxHeader; }

 private:
  static constexpr std::size_t kBlock = 4096;
  std::istream& in_;
  std::string text_;
  std::size_t pos_ = 0;   // start of the next line
  std::size_t scan_ = 0;  // text_ before this has no '\n' after pos_
  bool terminated_ = false;
};

}  // namespace sonomesh::volume::internal
