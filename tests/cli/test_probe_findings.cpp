// The bad-input probe's findings of issue #45, each as the tool meets it: the
// message names what was asked and what is there (sizes, memory, widths,
// folders), exit code 1 or 2, and never a C++ stack trace.
#include <filesystem>

#include "cli_fixtures.h"
#include "flat/core/tensor_io.h"

namespace fs = std::filesystem;
using namespace flat::test;

namespace {

// No libtorch stack trace and no bare allocator message in place of ours.
void check_no_trace(const std::string& output) {
  CHECK_THAT(output, !FLAT_CONTAINS("Exception raised from"));
  CHECK_THAT(output, !FLAT_CONTAINS("frame #"));
  CHECK_THAT(output, !FLAT_CONTAINS("enforce fail"));
}

// A 9-frame 16x24 scene with its 16x24_f5 latents (random dim-4 encoder), a
// stage config training a dim-4 decoder on it for one step, and that run.
struct Trained {
  std::string dir, synth, config, run;
};

const Trained& trained() {
  static Trained t = [] {
    Trained x;
    x.dir = fresh_dir("cli_probe").string();
    x.synth = x.dir + "/synth";
    REQUIRE(tool("flat_synth", {"--out", x.synth, "--count", "1", "--frames", "9", "--size", "16x24"}, x.dir, "synth")
                .rc == 0);
    REQUIRE(random_latents(x.synth, x.dir, "latents").rc == 0);
    x.run = x.dir + "/run";
    x.config = x.dir + "/stage.yaml";
    write_text(x.config, "run_dir: " + x.run +
                             "\nstage: probe\nsteps: 1\ndevice: cpu\nprecision: fp32\ninit: {from: scratch}\n"
                             "optim: {warmup_steps: 0}\nvalidation: {datasets: []}\n"
                             "data:\n  datasets: [{root: " + x.synth + ", weight: 1.0}]\n  height: 16\n  width: 24\n"
                             "  input_frames: 5\n  target_views: 2\n  workers: 0\n  latents: true\n"
                             "  incomplete_datasets: warn\n"
                             "pipeline:\n  model:\n    vae: {dim: 4}\nloss: {lambda_perc: 0.0}\n");
    const auto r = tool("flat_train", {"--config", x.config}, x.dir, "train");
    INFO(r.output);
    REQUIRE(r.rc == 0);
    return x;
  }();
  return t;
}

}  // namespace

TEST_CASE("probe: a stage whose size or window the scenes' latents lack says which set it needs and which they hold",
          "[cli][probe]") {
  const Trained& t = trained();
  // Another size, another window, and a window longer than the scene (9 frames).
  for (const auto& [set, needed] : {std::pair<std::string, std::string>{"data.height=24", "24x24_f5"},
                                    {"data.input_frames=9", "16x24_f9"}, {"data.input_frames=13", "16x24_f13"}}) {
    const auto r = tool("flat_train", {"--config", t.config, "--set", set, "--set", "run_dir=" + t.dir + "/run_bad"},
                        t.dir, "train_" + needed);
    INFO(set << "\n" << r.output);
    CHECK(r.rc == 1);
    // The last line (the error) carries it all, not only the log lines above it.
    const auto last = r.output.substr(r.output.rfind("[error]"));
    CHECK_THAT(last, FLAT_CONTAINS("latent set " + needed));
    CHECK_THAT(last, FLAT_CONTAINS("16x24_f5 (1 scene)"));
    CHECK_THAT(last, FLAT_CONTAINS(t.synth));
    if (needed == "16x24_f13") {
      CHECK_THAT(last, FLAT_CONTAINS("1 has 9 frames"));
      CHECK_THAT(last, FLAT_CONTAINS("shorter window (data.input_frames"));
    } else {
      CHECK_THAT(last, FLAT_CONTAINS("flat_latents --configs"));
    }
  }
}

TEST_CASE("probe: flat_bench loader and decoder at sizes that cannot fit name the size and the memory, no stack trace",
          "[cli][probe]") {
  const std::string d = fresh_dir("cli_probe_bench").string();
  const auto dec = tool("flat_bench", {"decoder", "--device", "cpu", "--latent-frames", "1", "--height", "100000",
                                       "--width", "100000", "--dim", "4", "--repeats", "1", "--warmup", "0", "--mode",
                                       "full"},
                        d, "decoder_huge");
  INFO(dec.output);
  CHECK(dec.rc == 1);
  CHECK_THAT(dec.output, FLAT_CONTAINS("100000x100000"));
  CHECK_THAT(dec.output, FLAT_CONTAINS("GiB"));
  CHECK_THAT(dec.output, FLAT_CONTAINS("available"));
  check_no_trace(dec.output);

  const std::string tmp = d + "/tmp";
  fs::create_directories(tmp);
  const int rc = run({binary("flat_bench"), "loader", "--scene-frames", "5", "--source-size", "16x24", "--size",
                      "100000x100000", "--window", "1", "--targets", "1", "--batch", "1", "--workers", "0", "--batches",
                      "1", "--warmup", "0", "--storage", "files"},
                     d + "/loader_huge.txt", {"TMPDIR=" + tmp, "OMP_NUM_THREADS=1", "OMP_WAIT_POLICY=PASSIVE"});
  const std::string out = read_file(d + "/loader_huge.txt");
  INFO(out);
  CHECK(rc == 1);
  CHECK_THAT(out, FLAT_CONTAINS("100000x100000"));
  CHECK_THAT(out, FLAT_CONTAINS("GiB"));
  CHECK_THAT(out, FLAT_CONTAINS("available"));
  check_no_trace(out);
  CHECK(fs::is_empty(tmp));
}

TEST_CASE("probe: flat_infer on a model of another width names both widths", "[cli][probe]") {
  const Trained& t = trained();
  // The trained dim-4 model without its metadata, away from its run folder's config.
  flat::Metadata meta;
  const auto tensors = flat::load_safetensors(t.run + "/model.safetensors", &meta);
  REQUIRE(meta.count("pipeline_config") == 1);
  const std::string bare = t.dir + "/bare/model.safetensors";
  fs::create_directories(t.dir + "/bare");
  flat::save_safetensors(bare, tensors);
  write_text(t.dir + "/dim8.yaml", "pipeline:\n  model:\n    vae: {dim: 8}\n");
  const auto r = tool("flat_infer", {"--model", bare, "--config", t.dir + "/dim8.yaml", "--scene",
                                     t.synth + "/room_000000", "--out", t.dir + "/infer_dim8", "--device", "cpu"},
                      t.dir, "infer_dim8");
  INFO(r.output);
  CHECK(r.rc == 1);
  CHECK_THAT(r.output, FLAT_CONTAINS("pipeline.model.vae.dim"));
  CHECK_THAT(r.output, FLAT_CONTAINS("file's decoder has dim 4"));
  CHECK_THAT(r.output, FLAT_CONTAINS("this config's has dim 8"));
  CHECK_THAT(r.output, FLAT_CONTAINS("decoder.conv1.weight"));
  CHECK_FALSE(fs::exists(t.dir + "/infer_dim8"));
}

TEST_CASE("probe: flat_bench loader --storage packed --data on a missing folder names the folder", "[cli][probe]") {
  const std::string d = fresh_dir("cli_probe_loader_data").string();
  for (const std::string mode : {"packed", "both", "files"}) {
    const auto r = tool("flat_bench", {"loader", "--storage", mode, "--data", d + "/no_such_dataset", "--batches", "1",
                                       "--warmup", "0", "--workers", "0"},
                        d, "loader_missing_" + mode);
    INFO(mode << "\n" << r.output);
    CHECK(r.rc == 1);
    CHECK_THAT(r.output, FLAT_CONTAINS(d + "/no_such_dataset"));
    CHECK_THAT(r.output, FLAT_CONTAINS("does not exist"));
    CHECK_THAT(r.output, !FLAT_CONTAINS("would pack"));
  }
}

TEST_CASE("probe: flat_import --depth on a missing folder names the flag and the folder; a {clip} pattern per clip",
          "[cli][probe]") {
  const std::string d = fresh_dir("cli_probe_depth").string();
  // One clip: a transforms.json capture (the images need not decode: the flags are checked first).
  write_text(d + "/capture/transforms.json",
             "{\"fl_x\": 20, \"fl_y\": 20, \"cx\": 12, \"cy\": 8, \"w\": 24, \"h\": 16, \"frames\": []}");
  const std::string missing = d + "/no_such_depth";
  const auto one = tool("flat_import", {"transforms", "--in", d + "/capture", "--out", d + "/scene", "--depth",
                                        missing},
                        d, "import_depth_missing");
  INFO(one.output);
  CHECK(one.rc == 2);
  CHECK_THAT(one.output, FLAT_CONTAINS("--depth: " + missing + ": no such folder (depth maps)"));
  CHECK_FALSE(fs::exists(d + "/scene"));
  // A pattern whose folder above {clip} is missing: refused at once, naming it.
  const auto pattern = tool("flat_import", {"transforms", "--in", d, "--out", d + "/scenes", "--depth",
                                            missing + "/{clip}/depth"},
                            d, "import_depth_pattern_missing");
  INFO(pattern.output);
  CHECK(pattern.rc == 2);
  CHECK_THAT(pattern.output, FLAT_CONTAINS("--depth: " + missing + "/{clip}/depth: no such folder " + missing));
  check_no_trace(one.output + pattern.output);
}
