// Dataset-scale import (issue #43): a folder of clips -> one scene folder per
// clip under an output root (docs/data_tools.md, "Batch import").
//   re10k:      `in` holds <clip>.txt camera files (RealEstate10K's train/ or
//               test/ split); frames are <frames_root>/<clip>/<timestamp>.png|jpg.
//   transforms: `in` holds scene folders, each with transforms.json (or
//               nerfstudio/transforms.json), images beside it (DL3DV: images_4/).
// Output: <out_root>/<clip>/, each scene staged and renamed into place by the
// importers (importers.h), so a failed clip leaves nothing behind.
//
// Every clip is imported on its own, `jobs` at a time (one intra-op thread
// each). A clip that fails (an unparsable camera file, a missing or unreadable
// frame, a pose that is no rotation, a bad depth map...) is logged with its
// reason and skipped; the others land. A rerun skips clips whose scene exists
// and reads (read_scene), so a killed run resumes where it stopped; staging
// folders that killed runs left in out_root are removed. Memory does not grow
// with the number of clips: scenes are dropped once written, only failures are kept.
// The run ends by writing <out_root>/import_summary.json (atomically).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "flat/data/importers.h"

namespace flat::data {

enum class BatchFormat { transforms, re10k };

// "transforms" | "re10k" (the flat_import subcommand names); throws on others.
BatchFormat batch_format(const std::string& name);

// Whether `in` names a batch rather than one clip: re10k: a folder (one clip
// is a .txt file); transforms: a folder without transforms.json of its own
// whose sub-folders (one of them at least) hold one.
bool is_batch_input(BatchFormat format, const std::string& in);

struct BatchImportOptions {
  BatchFormat format = BatchFormat::re10k;
  std::string in;           // folder of <clip>.txt (re10k) or of scene folders (transforms)
  std::string frames_root;  // re10k: frames of clip c in <frames_root>/<c>/
  std::string out_root;     // scenes land in <out_root>/<c>/
  // Per-clip options, applied to every clip. `name` must be empty (each scene
  // is named after its clip). With `overwrite` every clip is imported again
  // (each existing scene replaced only once its new one is complete);
  // without it existing scenes are kept and counted as already present.
  // Geometry maps: import.geometry's depth_dir / normals_dir are roots holding
  // one folder per clip, <root>/<c>/, or, when they contain "{clip}",
  // patterns in which it is replaced by the clip's name (DL3DV keeps the maps
  // inside each scene folder: "<in>/{clip}/depth"). A clip without its folder fails.
  ImportOptions import;
  int jobs = 0;                         // clips imported at once (0: min(cores, 4))
  double progress_log_seconds = 10.0;   // progress line period when stdout is no terminal
};

// The placeholder of a clip's name in batch-mode --depth / --normals values.
inline constexpr const char* kClipPlaceholder = "{clip}";

// The folder of clip `clip`'s maps for a batch --depth / --normals value:
// every "{clip}" in `root_or_pattern` replaced by the name; without one,
// <root>/<clip>. "" stays "" (no maps).
std::string clip_maps_folder(const std::string& root_or_pattern, const std::string& clip);

// One unit of work, as listed from the input folder.
struct BatchClip {
  std::string name;    // the clip / scene name, also the output folder's name
  std::string source;  // the camera .txt file or the transforms.json file
  std::string frames;  // re10k: the frames folder ("" for transforms)
};

struct BatchFailure {
  std::string name, source, reason;  // the reason names the file at fault (the importers' message)
};

struct BatchImportResult {
  int64_t clips = 0;     // listed in the input folder
  int64_t imported = 0;  // written by this run
  int64_t present = 0;   // already in out_root and readable (skipped)
  int64_t failed = 0;    // failures.size()
  double seconds = 0;
  int jobs = 0;                       // worker threads used
  std::vector<BatchFailure> failures;  // sorted by clip name
  std::string summary_path;            // <out_root>/import_summary.json
  bool ok() const { return failed == 0; }
};

// The clips of `in`, sorted by name (hidden entries skipped). re10k: every
// regular <clip>.txt; transforms: every sub-folder, with its transforms.json
// (a folder holding none is listed with that file as source and fails when
// imported, so that a broken download is reported, not silently dropped).
// Throws flat::Error when `in` is not a folder or lists no clip.
std::vector<BatchClip> list_batch_clips(const BatchImportOptions& options);

// Imports every clip of options.in; see the top of this file. Throws only for
// what stops the whole batch (bad options, no clips, an out_root that cannot
// be written); a clip's own failure is in the result. The summary file is
// written in either case of a finished run.
BatchImportResult import_batch(const BatchImportOptions& options);

// The summary's JSON text (written by import_batch; here for tests and tools).
std::string batch_summary_json(const BatchImportOptions& options, const BatchImportResult& result);

}  // namespace flat::data
