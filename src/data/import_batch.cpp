// Dataset-scale import: a folder of clips -> one scene per clip (import_batch.h).
#include "flat/data/import_batch.h"

#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <mutex>
#include <thread>
#include <utility>

#include <ATen/Parallel.h>
#include <c10/util/Exception.h>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"
#include "flat/core/progress.h"
#include "flat/data/scene.h"

namespace flat::data {

namespace fs = std::filesystem;

namespace {

constexpr const char* kSummaryFile = "import_summary.json";

bool hidden(const fs::path& p) {
  const std::string n = p.filename().string();
  return n.empty() || n[0] == '.';
}

// "<name><marker><pid>" (StagedDir's staging folder ".incomplete-<pid>" or the
// old scene it moves aside while replacing, ".old-<pid>"): returns the pid, or 0.
long staging_pid(const std::string& name) {
  for (const char* marker : {".incomplete-", ".old-"}) {
    const auto at = name.rfind(marker);
    if (at == std::string::npos || at == 0) continue;
    const std::string digits = name.substr(at + std::char_traits<char>::length(marker));
    if (digits.empty() || digits.find_first_not_of("0123456789") != std::string::npos) continue;
    return std::atol(digits.c_str());
  }
  return 0;
}

bool process_alive(long pid) { return pid > 0 && (::kill(pid_t(pid), 0) == 0 || errno == EPERM); }

// Deletes a folder tree entry by entry (the project avoids std::filesystem::remove_all
// on non-empty folders: in some builds it resolves to libtorch's bundled copy).
void remove_tree(const fs::path& root) {
  std::error_code ec;
  std::vector<fs::path> paths;
  for (auto it = fs::recursive_directory_iterator(root, ec); !ec && it != fs::recursive_directory_iterator();
       it.increment(ec))
    paths.push_back(it->path());
  std::sort(paths.begin(), paths.end(),
            [](const fs::path& a, const fs::path& b) { return a.string().size() > b.string().size(); });
  for (const auto& p : paths) fs::remove(p, ec);
  fs::remove(root, ec);
}

// Staging folders of killed runs in out_root (their pid is gone): the importers
// remove those of a clip they import again; these are the rest (a clip that
// landed since, or that is no longer listed).
void remove_stale_staging(const std::string& out_root) {
  std::error_code ec;
  for (auto it = fs::directory_iterator(out_root, ec); !ec && it != fs::directory_iterator(); it.increment(ec)) {
    const std::string name = it->path().filename().string();
    const long pid = staging_pid(name);
    if (pid <= 0 || pid == long(::getpid()) || process_alive(pid)) continue;
    std::error_code type_ec;
    if (!it->is_directory(type_ec)) continue;
    spdlog::warn("{}: removing '{}', left by an import that did not finish", out_root, it->path().string());
    remove_tree(it->path());
  }
}

// The message of the exception in flight, without libtorch's stack trace.
std::string current_reason() {
  try {
    throw;
  } catch (const Error& e) {
    return e.what();
  } catch (const fs::filesystem_error& e) {
    return e.what();
  } catch (const c10::Error& e) {
    return e.what_without_backtrace();
  } catch (const std::exception& e) {
    return e.what();
  } catch (...) {
    return "unknown error (not a std::exception)";
  }
}

// Runs fn(0..n-1) on `jobs` threads, each with one intra-op thread (as the
// loader's workers: N clips with a full OpenMP team each would oversubscribe
// the cores). fn must not throw. The caller's thread count is set again after
// (a worker's at::set_num_threads also sets the default of later threads).
void parallel_for(int64_t n, int jobs, const std::function<void(int64_t)>& fn) {
  if (n <= 0) return;
  const int own = at::get_num_threads();
  std::atomic<int64_t> next{0};
  std::vector<std::thread> threads;
  const int64_t count = std::min<int64_t>(std::max(jobs, 1), n);
  for (int64_t t = 0; t < count; ++t)
    threads.emplace_back([&] {
      at::set_num_threads(1);
      for (int64_t i = next++; i < n; i = next++) fn(i);
    });
  for (auto& t : threads) t.join();
  at::set_num_threads(own);
}

// The transforms.json of a scene folder: <dir>/transforms.json, else
// <dir>/nerfstudio/transforms.json (DL3DV's benchmark layout), else "".
std::string find_transforms(const fs::path& dir) {
  std::error_code ec;
  for (const fs::path& p : {dir / "transforms.json", dir / "nerfstudio" / "transforms.json"})
    if (fs::is_regular_file(p, ec)) return p.string();
  return "";
}

bool same_path(const fs::path& a, const fs::path& b) {
  std::error_code ea, eb;
  const fs::path ca = fs::weakly_canonical(a, ea), cb = fs::weakly_canonical(b, eb);
  return !ea && !eb && ca == cb;
}

// One clip: options with the clip's geometry folders, then the importer.
void import_clip(const BatchClip& clip, const BatchImportOptions& options) {
  ImportOptions o = options.import;
  o.name.clear();  // each scene is named after its output folder, the clip
  // In batch mode the depth / normals options are roots holding one folder per
  // clip, or patterns naming it with {clip}.
  const std::string depth_root = o.geometry.depth_dir, normals_root = o.geometry.normals_dir;
  auto clip_dir = [&](const std::string& root, const char* kind) -> std::string {
    if (root.empty()) return "";
    const std::string dir = clip_maps_folder(root, clip.name);
    std::error_code ec;
    if (!fs::is_directory(dir, ec))
      fail(dir + ": no " + kind + " folder for clip '" + clip.name + "' (" +
           (root.find(kClipPlaceholder) != std::string::npos
                ? "the " + std::string(kind) + " option '" + root + "' with {clip} replaced by the clip's name"
                : "in batch mode the " + std::string(kind) +
                      " option names a root holding one folder per clip, or a pattern with {clip}") +
           ")");
    return dir;
  };
  const std::string depth = clip_dir(depth_root, "depth"), normals = clip_dir(normals_root, "normals");
  o.geometry.depth_dir = depth;
  o.geometry.normals_dir = normals;
  const std::string out = (fs::path(options.out_root) / clip.name).string();
  if (options.format == BatchFormat::re10k) {
    import_re10k(clip.source, clip.frames, out, o);
  } else {
    std::error_code ec;
    if (!fs::is_regular_file(clip.source, ec))
      fail(fs::path(clip.source).parent_path().string() +
           ": no transforms.json (nor nerfstudio/transforms.json) in this scene folder");
    import_transforms_json(clip.source, out, o);
  }
}

const char* format_name(BatchFormat f) { return f == BatchFormat::re10k ? "re10k" : "transforms"; }

}  // namespace

std::string clip_maps_folder(const std::string& root_or_pattern, const std::string& clip) {
  if (root_or_pattern.empty()) return "";
  const std::string placeholder = kClipPlaceholder;
  if (root_or_pattern.find(placeholder) == std::string::npos) return (fs::path(root_or_pattern) / clip).string();
  std::string dir = root_or_pattern;
  for (auto at = dir.find(placeholder); at != std::string::npos; at = dir.find(placeholder, at + clip.size()))
    dir.replace(at, placeholder.size(), clip);
  return dir;
}

BatchFormat batch_format(const std::string& name) {
  if (name == "re10k") return BatchFormat::re10k;
  if (name == "transforms") return BatchFormat::transforms;
  fail("import: unknown format '" + name + "' (transforms or re10k)");
}

bool is_batch_input(BatchFormat format, const std::string& in) {
  std::error_code ec;
  if (!fs::is_directory(in, ec)) return false;
  if (format == BatchFormat::re10k) return true;
  if (fs::exists(fs::path(in) / "transforms.json", ec)) return false;
  for (auto it = fs::directory_iterator(in, ec); !ec && it != fs::directory_iterator(); it.increment(ec)) {
    std::error_code type_ec;
    if (it->is_directory(type_ec) && !hidden(it->path()) && !find_transforms(it->path()).empty()) return true;
  }
  return false;
}

std::vector<BatchClip> list_batch_clips(const BatchImportOptions& o) {
  std::error_code ec;
  if (!fs::is_directory(o.in, ec)) fail(o.in + ": not a folder (batch import lists the clips of a folder)");
  std::vector<BatchClip> clips;
  for (auto it = fs::directory_iterator(o.in, ec); !ec && it != fs::directory_iterator(); it.increment(ec)) {
    const fs::path p = it->path();
    if (hidden(p)) continue;
    std::error_code type_ec;
    if (o.format == BatchFormat::re10k) {
      if (!it->is_regular_file(type_ec) || p.extension() != ".txt") continue;
      const std::string name = p.stem().string();
      clips.push_back({name, p.string(), (fs::path(o.frames_root) / name).string()});
    } else {
      if (!it->is_directory(type_ec)) continue;
      // Not a scene: the output root (or its staging folders) when it lies inside the input.
      if (staging_pid(p.filename().string()) > 0 || same_path(p, o.out_root)) continue;
      std::string json = find_transforms(p);
      clips.push_back({p.filename().string(), json.empty() ? (p / "transforms.json").string() : json, ""});
    }
  }
  if (ec) fail(o.in + ": cannot list the folder (" + ec.message() + ")");
  if (clips.empty())
    fail(o.in + (o.format == BatchFormat::re10k ? ": no <clip>.txt camera files" : ": no scene folders"));
  std::sort(clips.begin(), clips.end(), [](const BatchClip& a, const BatchClip& b) { return a.name < b.name; });
  return clips;
}

std::string batch_summary_json(const BatchImportOptions& o, const BatchImportResult& r) {
  nlohmann::ordered_json j;  // in the order written: what ran, the counts, then the failures
  j["format"] = format_name(o.format);
  j["in"] = o.in;
  if (o.format == BatchFormat::re10k) j["frames_dir"] = o.frames_root;
  j["out"] = o.out_root;
  j["jobs"] = r.jobs;
  j["clips"] = r.clips;
  j["imported"] = r.imported;
  j["already_present"] = r.present;
  j["failed"] = r.failed;
  j["seconds"] = r.seconds;
  // Clips this run imported per minute of its wall time (present ones cost little and are not counted).
  j["clips_per_minute"] = Progress::per_minute(r.imported, r.seconds);
  nlohmann::ordered_json failures = nlohmann::ordered_json::array();
  for (const auto& f : r.failures) failures.push_back({{"name", f.name}, {"source", f.source}, {"reason", f.reason}});
  j["failures"] = std::move(failures);
  return j.dump(2) + "\n";
}

BatchImportResult import_batch(const BatchImportOptions& o) {
  const auto start = std::chrono::steady_clock::now();
  FLAT_CHECK(!o.out_root.empty(), "batch import: empty output root");
  FLAT_CHECK(o.import.name.empty(), "batch import: a scene name applies to one clip; batch scenes are named after their clips");
  if (o.format == BatchFormat::re10k) {
    std::error_code ec;
    FLAT_CHECK(!o.frames_root.empty(), "batch import re10k: no frames root (--frames-dir)");
    if (!fs::is_directory(o.frames_root, ec))
      fail(o.frames_root + ": not a folder (re10k batch: --frames-dir holds one folder of frames per clip)");
  }
  auto clips = list_batch_clips(o);
  std::error_code ec;
  fs::create_directories(o.out_root, ec);
  if (ec) fail(o.out_root + ": cannot create the output root (" + ec.message() + ")");
  remove_stale_staging(o.out_root);

  BatchImportResult r;
  r.clips = int64_t(clips.size());
  r.jobs = o.jobs > 0 ? o.jobs : int(std::clamp<unsigned>(std::thread::hardware_concurrency(), 1u, 4u));
  r.summary_path = (fs::path(o.out_root) / kSummaryFile).string();
  std::mutex mutex;  // guards r.failures, r.imported, r.present and the progress line
  auto add_failure = [&](const BatchClip& clip, const std::string& reason) {
    spdlog::warn("{}: skipped: {}", clip.name, reason);
    std::lock_guard<std::mutex> lock(mutex);
    r.failures.push_back({clip.name, clip.source, reason});
  };

  // Pass 1: which clips are done already (their scene reads). Parallel: each
  // check reads a scene.json and stats its files.
  std::vector<char> todo(clips.size(), 0);
  parallel_for(int64_t(clips.size()), r.jobs, [&](int64_t i) {
    const BatchClip& clip = clips[size_t(i)];
    const fs::path out = fs::path(o.out_root) / clip.name;
    std::error_code e;
    const bool exists = fs::exists(out, e) && !(fs::is_directory(out, e) && fs::is_empty(out, e));
    if (!exists || o.import.overwrite) {
      todo[size_t(i)] = 1;
      return;
    }
    try {
      read_scene(out.string(), true);
      std::lock_guard<std::mutex> lock(mutex);
      ++r.present;
    } catch (...) {
      add_failure(clip, out.string() + ": exists but is not a readable scene (" + current_reason() +
                            "); remove it, or pass --overwrite to import the clip again");
    }
  });
  const int64_t to_import = std::count(todo.begin(), todo.end(), 1);
  spdlog::info("{} {} clips in {}: {} to import, {} already in {}{}; {} at a time", format_name(o.format), r.clips,
               o.in, to_import, r.present, o.out_root,
               r.failures.empty() ? "" : ", " + std::to_string(r.failures.size()) + " unreadable there", r.jobs);

  // Pass 2: the imports. Each scene is dropped once written: memory stays flat.
  {
    Progress progress("import clips", to_import, o.progress_log_seconds);
    parallel_for(int64_t(clips.size()), r.jobs, [&](int64_t i) {
      if (!todo[size_t(i)]) return;
      const BatchClip& clip = clips[size_t(i)];
      bool ok = false;
      try {
        import_clip(clip, o);
        ok = true;
      } catch (...) {
        add_failure(clip, current_reason());
      }
      std::lock_guard<std::mutex> lock(mutex);
      if (ok) ++r.imported;
      progress.step(1, {{"failed", double(r.failures.size())}});
    });
    progress.finish();
  }

  std::sort(r.failures.begin(), r.failures.end(),
            [](const BatchFailure& a, const BatchFailure& b) { return a.name < b.name; });
  r.failed = int64_t(r.failures.size());
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  write_file_atomic(r.summary_path, batch_summary_json(o, r));
  spdlog::info("{} clips: {} imported, {} already present, {} failed in {} ({:.1f} clips/min); summary: {}", r.clips,
               r.imported, r.present, r.failed, Progress::format_duration(r.seconds),
               Progress::per_minute(r.imported, r.seconds), r.summary_path);
  if (r.failed)
    spdlog::warn("{} of {} clips failed (listed with their reasons in {}); the others are in {}", r.failed, r.clips,
                 r.summary_path, o.out_root);
  return r;
}

}  // namespace flat::data
