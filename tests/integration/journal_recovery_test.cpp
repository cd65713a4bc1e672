// Reopening a journal that an earlier run left: torn and garbage lines set aside, the epoch and
// the sequences already written carried over.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "daemon/internal/journal.h"

namespace fs = std::filesystem;
using sonomesh::daemon::Journal;
using sonomesh::daemon::JournalStatus;
using sonomesh::daemon::repair_jsonl;

namespace {

class JournalRecovery : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("sm_journal_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path file() const { return dir_ / "journal.jsonl"; }
  void write(const std::string& bytes) const {
    std::ofstream(file(), std::ios::binary | std::ios::trunc) << bytes;
  }
  std::string read(const fs::path& p) const {
    std::ifstream in(p, std::ios::binary);
    return std::string((std::istreambuf_iterator<char>(in)), {});
  }
  fs::path dir_;
};

}  // namespace

TEST_F(JournalRecovery, TornLastLineIsSetAsideAndWholeLinesStay) {
  write("{\"sequence\":0,\"status\":\"processed\"}\n{\"sequence\":1,\"sta");
  const auto repair = repair_jsonl(file());
  EXPECT_EQ(repair.whole_lines, 1u);
  EXPECT_EQ(repair.set_aside, 1u);
  EXPECT_EQ(read(file()), "{\"sequence\":0,\"status\":\"processed\"}\n");
  EXPECT_EQ(read(repair.set_aside_path), "{\"sequence\":1,\"sta\n");
  // A second look finds nothing more to do.
  EXPECT_EQ(repair_jsonl(file()).set_aside, 0u);
}

TEST_F(JournalRecovery, GarbageAnywhereIsSetAsideAndAWholeLastLineGetsItsNewline) {
  write("{\"sequence\":0,\"status\":\"lost\"}\n" + std::string(16, '\0') +
        "\n[1,2]\n{\"sequence\":1,\"status\":\"lost\"}");
  const auto repair = repair_jsonl(file());
  EXPECT_EQ(repair.whole_lines, 2u);
  EXPECT_EQ(repair.set_aside, 2u);  // the NUL block and a JSON value that is not an object
  EXPECT_EQ(read(file()),
            "{\"sequence\":0,\"status\":\"lost\"}\n{\"sequence\":1,\"status\":\"lost\"}\n");

  write("{\"a\":1}");
  const auto whole = repair_jsonl(file());
  EXPECT_EQ(whole.set_aside, 0u);
  EXPECT_TRUE(whole.set_aside_path.empty());
  EXPECT_EQ(read(file()), "{\"a\":1}\n");
}

TEST_F(JournalRecovery, ReopenedJournalGoesOnInTheLastEpochWithItsSequencesClaimed) {
  {
    Journal first(file());
    for (std::uint64_t s : {5, 3, 4, 1}) {  // out of order, as worker and acquisition write
      ASSERT_TRUE(first.claim(s));
      first.write(s, JournalStatus::Processed, {});
    }
    first.write(std::nullopt, JournalStatus::Rejected, {{"reason", "bad header"}});
  }
  {
    Journal second(file());
    EXPECT_EQ(second.epoch(), 0u);
    EXPECT_EQ(second.highest_before(), 5u);
    for (std::uint64_t s : {1, 3, 4, 5}) {
      EXPECT_TRUE(second.written_before(s)) << s;
      EXPECT_FALSE(second.claim(s)) << s;
    }
    EXPECT_FALSE(second.written_before(2));
    using Holes = std::vector<std::pair<std::uint64_t, std::uint64_t>>;
    EXPECT_EQ(second.holes_before(), (Holes{{2, 1}}));
    EXPECT_TRUE(second.claim(2));  // no line yet: it may still get one
    second.write(2, JournalStatus::Lost, {{"reason", "gap"}});
    second.new_epoch();
    ASSERT_TRUE(second.claim(0));
    second.write(0, JournalStatus::Processed, {});
  }
  Journal third(file());
  EXPECT_EQ(third.epoch(), 1u);  // only the last epoch's sequences count
  EXPECT_EQ(third.highest_before(), 0u);
  EXPECT_TRUE(third.written_before(0));
  EXPECT_FALSE(third.written_before(3));
  EXPECT_TRUE(third.claim(3));
  EXPECT_EQ(third.repair().whole_lines, 7u);
}
