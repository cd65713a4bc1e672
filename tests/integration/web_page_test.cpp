// The live page in a real browser (Debian's headless Chromium over the DevTools pipe): the daemon
// on the simulator, the page loaded from it, the 3D view and the slices drawn (not blank), the
// numbers changing when the next volume arrives, and the "probe disconnected" state.
#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "cdp_pipe.h"
#include "child_process.h"

namespace {

using namespace sonomesh::testing;

constexpr const char* kPageState =
    "window.sonomesh ? {events: sonomesh.events, processed: sonomesh.processed,"
    " lastSequence: sonomesh.lastSequence, meshLoads: sonomesh.meshLoads,"
    " meshVertices: sonomesh.meshVertices, slicesLoaded: sonomesh.slicesLoaded,"
    " sourceState: sonomesh.sourceState,"
    " shown: document.getElementById('n-sequence').textContent,"
    " genus: document.getElementById('n-genus').textContent,"
    " banner: document.getElementById('banner').className + '|' +"
    " document.getElementById('banner').textContent} : null";

// Grey-level standard deviation of each element's box in the screenshot.
std::vector<double> region_contrast(const std::string& png, const nlohmann::json& rects) {
  const std::vector<uchar> bytes(png.begin(), png.end());
  const cv::Mat image = cv::imdecode(bytes, cv::IMREAD_GRAYSCALE);
  std::vector<double> out;
  for (const auto& r : rects) {
    cv::Rect box(static_cast<int>(r[0].get<double>()), static_cast<int>(r[1].get<double>()),
                 static_cast<int>(r[2].get<double>()), static_cast<int>(r[3].get<double>()));
    box &= cv::Rect(0, 0, image.cols, image.rows);
    if (box.area() < 100) {
      out.push_back(0);
      continue;
    }
    cv::Scalar mean, stddev;
    cv::meanStdDev(image(box), mean, stddev);
    out.push_back(stddev[0]);
  }
  return out;
}

TEST(LivePage, DrawsMeshAndSlicesAndUpdatesWithoutReload) {
  if (!Chromium::available()) {
    GTEST_SKIP() << "no browser: /usr/bin/chromium is not installed (scripts/setup.sh installs it)";
  }
  ScratchDir dir("page");
  Child daemon({SONOMESHD_EXE, "run", "--source", "sim:cyst-needle?rate=2&size=48", "--out",
                (dir / "out").string(), "--http", "127.0.0.1:0"},
               dir / "daemon");
  const int port = http_port_of(dir / "out");
  ASSERT_GT(port, 0) << daemon.stderr_text();

  Chromium browser(dir.path());
  ASSERT_TRUE(browser.started());
  const auto session = browser.open_page("http://127.0.0.1:" + std::to_string(port) + "/");
  ASSERT_TRUE(session) << browser.last_error();

  nlohmann::json state;
  auto read_state = [&] {
    state = browser.evaluate(*session, kPageState).value_or(nlohmann::json());
    return state.is_object();
  };
  ASSERT_TRUE(wait_until(
      [&] { return read_state() && state["meshLoads"] >= 1 && state["slicesLoaded"] >= 3; }, 90s,
      250ms))
      << state.dump() << " " << browser.last_error();
  EXPECT_GT(state["meshVertices"].get<int>(), 100);
  EXPECT_NE(state["shown"], "–");

  const auto rects = browser.evaluate(
      *session,
      "['#view3d canvas', '#slice-axial', '#slice-coronal', '#slice-sagittal'].map((s) => {"
      " const r = document.querySelector(s).getBoundingClientRect();"
      " return [r.x, r.y, r.width, r.height]; })");
  ASSERT_TRUE(rects && rects->size() == 4);
  const auto png = browser.screenshot(*session);
  ASSERT_TRUE(png) << browser.last_error();
  const std::vector<double> contrast = region_contrast(*png, *rects);
  // A blank canvas or an image that did not load is one flat colour: deviation ~0. The mesh on
  // its dark background and speckled slices measure tens of grey levels.
  for (std::size_t i = 0; i < contrast.size(); ++i) {
    EXPECT_GT(contrast[i], 8.0) << "region " << (*rects)[i].dump() << " is blank";
  }

  // The next volume: the numbers and the mesh change in the same page, without a reload.
  const nlohmann::json first = state;
  ASSERT_TRUE(wait_until(
      [&] {
        return read_state() && state["shown"] != first["shown"] &&
               state["meshLoads"] > first["meshLoads"];
      },
      60s, 250ms))
      << first.dump() << " -> " << state.dump();
  EXPECT_GT(state["processed"].get<int>(), first["processed"].get<int>());
  EXPECT_EQ(state["sourceState"], "connected");

  // A click on the axial slice's centre seeds the next volume there (POST /seed).
  ASSERT_TRUE(browser.evaluate(*session,
                               "(() => { const img = document.getElementById('slice-axial');"
                               " const r = img.getBoundingClientRect();"
                               " img.dispatchEvent(new MouseEvent('click', {bubbles: true,"
                               " clientX: r.x + r.width / 2, clientY: r.y + r.height / 2}));"
                               " return true; })()"));
  nlohmann::json seed_event;
  EXPECT_TRUE(wait_until(
      [&] {
        for (const auto& e : read_jsonl(dir / "out" / "events.jsonl")) {
          if (e.value("event", "") == "seed_set") seed_event = e;
        }
        return seed_event.is_object();
      },
      20s, 100ms));
  if (seed_event.is_object()) {
    // The 48³ volume of 0.5 mm voxels: the centre column is near 12 mm in x and y.
    EXPECT_NEAR(seed_event["seed_mm"][0].get<double>(), 11.75, 0.6);
    EXPECT_NEAR(seed_event["seed_mm"][1].get<double>(), 11.75, 0.6);
  }
  daemon.signal(SIGINT);
  EXPECT_EQ(daemon.wait(30s), 0) << daemon.stderr_text();
}

TEST(LivePage, SaysSoWhenTheProbeIsDisconnected) {
  if (!Chromium::available()) {
    GTEST_SKIP() << "no browser: /usr/bin/chromium is not installed (scripts/setup.sh installs it)";
  }
  ScratchDir dir("nosrc");
  // A probe socket nobody serves: the daemon waits for it (state "connecting").
  Child daemon({SONOMESHD_EXE, "run", "--source", "unix:" + (dir / "absent.sock").string(), "--out",
                (dir / "out").string(), "--http", "127.0.0.1:0"},
               dir / "daemon");
  const int port = http_port_of(dir / "out");
  ASSERT_GT(port, 0) << daemon.stderr_text();
  Chromium browser(dir.path());
  const auto session = browser.open_page("http://127.0.0.1:" + std::to_string(port) + "/");
  ASSERT_TRUE(session) << browser.last_error();
  nlohmann::json state;
  ASSERT_TRUE(wait_until(
      [&] {
        state = browser.evaluate(*session, kPageState).value_or(nlohmann::json());
        return state.is_object() && state["sourceState"] == "connecting";
      },
      30s, 250ms))
      << state.dump();
  const std::string banner = state["banner"];
  EXPECT_EQ(banner.find("hidden"), std::string::npos) << banner;
  EXPECT_NE(banner.find("Probe disconnected"), std::string::npos) << banner;
  EXPECT_EQ(state["processed"], 0);
  daemon.signal(SIGINT);
  EXPECT_EQ(daemon.wait(30s), 0) << daemon.stderr_text();
}

}  // namespace
