// The tools as a new user meets them (issue #13): bad input is refused up
// front with exit code 1 (runtime) or 2 (usage) and a message naming what is
// wrong; a failed or refused run leaves earlier outputs byte-identical; every
// tool shares --version, --log-level, --device and the exit codes (docs/cli.md).
#include <filesystem>

#include <torch/torch.h>

#include "cli_fixtures.h"
#include "flat/core/image_io.h"
#include "flat/core/tensor_io.h"
#include "flat/data/scene.h"

namespace fs = std::filesystem;
using namespace flat::test;

namespace {

// Made once per test process: a 5-frame synthetic room, a transforms.json
// capture of 3 PNG frames, a random latent and small tensor files.
struct Fixtures {
  std::string root, synth, capture, bad_capture, latent, video_ok;
};

void write_capture(const std::string& dir, bool truncate_last) {
  std::string frames;
  for (int i = 0; i < 3; ++i) {
    const std::string name = "images/" + std::to_string(i) + ".png";
    // Without OpenImageIO (the GPU machine's build) the files only have to
    // exist for the table's rows; the import tests that decode them skip.
    if (flat::image_io_available()) {
      flat::write_image(dir + "/" + name, torch::rand({3, 16, 24}));
    } else {
      write_text(dir + "/" + name, "not decoded in a build without OpenImageIO");
    }
    if (truncate_last && i == 2) fs::resize_file(dir + "/" + name, 40);  // a download cut short
    frames += std::string(i ? "," : "") + "{\"file_path\": \"" + name +
              "\", \"transform_matrix\": [[1,0,0," + std::to_string(0.1 * i) + "],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}";
  }
  write_text(dir + "/transforms.json",
             "{\"fl_x\": 20, \"fl_y\": 20, \"cx\": 12, \"cy\": 8, \"w\": 24, \"h\": 16, \"frames\": [" + frames + "]}");
}

const Fixtures& fixtures() {
  static Fixtures f = [] {
    Fixtures x;
    x.root = fresh_dir("cli").string();
    x.synth = x.root + "/synth";
    REQUIRE(tool("flat_synth", {"--out", x.synth, "--count", "1", "--frames", "5", "--size", "16x24"}, x.root,
                 "fixture_synth")
                .rc == 0);
    x.capture = x.root + "/capture";
    write_capture(x.capture, false);
    x.bad_capture = x.root + "/capture_truncated";
    write_capture(x.bad_capture, true);
    x.latent = x.root + "/latent.safetensors";
    flat::save_safetensors(x.latent, {{"latent", torch::randn({1, 16, 2, 2, 3})}});
    x.video_ok = x.root + "/video.safetensors";
    flat::save_safetensors(x.video_ok, {{"video", torch::rand({1, 3, 5, 16, 16}) * 2 - 1}});
    flat::save_safetensors(x.root + "/video_int64.safetensors",
                           {{"video", torch::randint(0, 2, {1, 3, 5, 16, 16}, torch::kLong)}});
    flat::save_safetensors(x.root + "/video_255.safetensors", {{"video", torch::rand({1, 3, 5, 16, 16}) * 255}});
    flat::save_safetensors(x.root + "/weights_nan.safetensors",
                           {{"encoder.conv1.weight", torch::full({4, 3, 3, 3, 3}, NAN)}});
    flat::save_safetensors(x.root + "/weights_u8.safetensors",
                           {{"encoder.conv1.weight", torch::zeros({4, 3, 3, 3, 3}, torch::kByte)}});
    // A PLY header claiming 4e9 faces over a few bytes of body.
    write_text(x.root + "/huge.ply",
               "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
               "property float z\nelement face 4000000000\nproperty list uchar int vertex_indices\n"
               "property float red\nproperty float green\nproperty float blue\nproperty float opacity\n"
               "property float sigma\nend_header\n" +
                   std::string(36, '\0'));
    const std::string cam = "{\"width\": 300000, \"height\": 300000, \"intrinsics\": [1, 1, 0.5, 0.5], "
                            "\"c2w\": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}";
    write_text(x.root + "/huge_cams.json", "{\"version\": 1, \"cameras\": [" + cam + "," + cam + "]}");
    write_text(x.root + "/cams_small.json",
               "{\"version\": 1, \"cameras\": [{\"width\": 8, \"height\": 8, \"intrinsics\": [1, 1, 0.5, 0.5], "
               "\"c2w\": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]}");
    // A valid one-triangle PLY: three vertices, then vertex count 3, indices 0, 1, 2 (int32),
    // colour, opacity and sigma (floats), all little-endian.
    std::string body;
    auto put = [&body](auto v) { body.append(reinterpret_cast<const char*>(&v), sizeof(v)); };
    for (float v : {0.f, 0.f, 2.f, 0.5f, 0.f, 2.f, 0.f, 0.5f, 2.f}) put(v);
    put(uint8_t(3));
    for (int32_t i : {0, 1, 2}) put(i);
    for (float v : {0.8f, 0.4f, 0.2f, 0.9f, 1.f}) put(v);
    write_text(x.root + "/one.ply",
               "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
               "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
               "property float red\nproperty float green\nproperty float blue\nproperty float opacity\n"
               "property float sigma\nend_header\n" +
                   body);
    // A diffusers folder whose weights hold NaN: the folder is accepted, the NaN named.
    flat::save_safetensors(x.root + "/diffusers/diffusion_pytorch_model.safetensors",
                           {{"encoder.conv_in.weight", torch::full({4, 3, 3, 3, 3}, NAN)}});
    return x;
  }();
  return f;
}

// One row of the table: a command, its exit code and the words its message must hold.
struct Case {
  std::string name, program;
  std::vector<std::string> args;
  int rc;
  std::vector<std::string> words;
};

std::vector<std::string> expand(const std::vector<std::string>& args, const Fixtures& f) {
  std::vector<std::string> out;
  for (std::string a : args) {
    for (const auto& [key, value] : {std::pair<std::string, std::string>{"{R}", f.root}, {"{SYNTH}", f.synth}}) {
      const auto at = a.find(key);
      if (at != std::string::npos) a.replace(at, key.size(), value);
    }
    out.push_back(a);
  }
  return out;
}

void check_cases(const std::vector<Case>& cases) {
  const Fixtures& f = fixtures();
  for (const auto& c : cases) {
    INFO(c.name << ": " << c.program);
    const ToolResult r = tool(c.program, expand(c.args, f), f.root, "case_" + c.name);
    INFO(r.output);
    CHECK(r.rc == c.rc);
    for (const auto& w : c.words) CHECK_THAT(r.output, FLAT_CONTAINS(w));
    // Never a C++ stack trace or an allocator's bare message in place of ours.
    CHECK_THAT(r.output, !FLAT_CONTAINS("Exception raised from"));
    CHECK_THAT(r.output, !FLAT_CONTAINS("std::bad_alloc"));
  }
}

const std::vector<std::string> kTools = {"flat_import", "flat_synth", "flat_vae",  "flat_latents", "flat_pack",
                                         "flat_render", "flat_train", "flat_infer", "flat_eval",    "flat_bench",
                                         "flat_mesh"};

}  // namespace

TEST_CASE("every tool: --version exits 0, an unknown flag is a usage error (2), --help shows defaults", "[cli]") {
  const Fixtures& f = fixtures();
  for (const auto& t : kTools) {
    INFO(t);
    auto v = tool(t, {"--version"}, f.root, t + "_version");
    CHECK(v.rc == 0);
    CHECK_THAT(v.output, FLAT_CONTAINS(t + " 0.1.0"));
    auto u = tool(t, {"--no-such-flag"}, f.root, t + "_unknown");
    CHECK(u.rc == 2);
    CHECK_THAT(u.output, FLAT_CONTAINS("--help"));  // CLI11: "Run with --help for more information."
    CHECK(tool(t, {"--help"}, f.root, t + "_help").rc == 0);
  }
  // Defaults are shown, and --device/--log-level mean the same in every tool that computes.
  for (const auto& t : {"flat_latents", "flat_render", "flat_infer", "flat_eval", "flat_mesh"}) {
    INFO(t);
    auto h = tool(t, {"--help"}, f.root, std::string(t) + "_help2");
    CHECK_THAT(h.output, FLAT_CONTAINS("--device"));
    CHECK_THAT(h.output, FLAT_CONTAINS("auto"));
    CHECK_THAT(h.output, FLAT_CONTAINS("--log-level"));
    CHECK_THAT(h.output, FLAT_CONTAINS("--threads"));  // tools run side by side need to share the cores
  }
  CHECK_THAT(tool("flat_synth", {"--help"}, f.root, "flat_synth_help2").output, FLAT_CONTAINS("--threads"));
  for (const auto& sub : {"encode", "decode"}) {
    auto h = tool("flat_vae", {sub, "--help"}, f.root, std::string("flat_vae_help_") + sub);
    CHECK_THAT(h.output, FLAT_CONTAINS("--precision"));
    CHECK_THAT(h.output, FLAT_CONTAINS("--device"));
    CHECK_THAT(h.output, FLAT_CONTAINS("--threads"));
    // The default, as CLI11 shows it: "=auto" (Debian's 2.3) or "[auto]" (2.4 and later).
    const bool shows_default = h.output.find("=auto") != std::string::npos || h.output.find("[auto]") != std::string::npos;
    CHECK(shows_default);
  }
  for (const auto& sub : {"decoder", "raster"}) {
    auto h = tool("flat_bench", {sub, "--help"}, f.root, std::string("flat_bench_help_") + sub);
    CHECK_THAT(h.output, FLAT_CONTAINS("--device"));
  }
  CHECK_THAT(tool("flat_bench", {"raster", "--help"}, f.root, "raster_help").output, FLAT_CONTAINS("--workload"));
}

TEST_CASE("tools restart once with sleeping OpenMP threads, unless the user chose a wait policy", "[cli]") {
  // libgomp prints the policy it took from the environment as it loads
  // (OMP_DISPLAY_ENV); GOMP_SPINCOUNT tells its default (300000 spins) from
  // PASSIVE (0). The three ways in: cli::parse (flat_synth), flat_train's own
  // parse, flat_bench before its parse. The test's environment must not
  // decide the policy for the tools.
  const Fixtures& f = fixtures();
  std::map<std::string, std::string> saved;
  for (const char* name : {"OMP_WAIT_POLICY", "GOMP_SPINCOUNT"})
    if (const char* v = std::getenv(name)) {
      saved[name] = v;
      unsetenv(name);
    }
  const std::string synth_out = f.root + "/omp_synth";
  const std::vector<std::vector<std::string>> runs = {
      {binary("flat_synth"), "--out", synth_out, "--count", "1", "--frames", "1", "--size", "16x16", "--overwrite"},
      {binary("flat_train"), "--help-config"},
      {binary("flat_bench"), "--version"}};
  const std::string spin = "GOMP_SPINCOUNT = '";
  for (const auto& argv : runs) {
    INFO(argv[0]);
    const std::string log = f.root + "/omp_env.txt";
    REQUIRE(run(argv, log, {"OMP_DISPLAY_ENV=VERBOSE", "OMP_NUM_THREADS=1"}) == 0);
    std::string out = read_file(log);
    INFO(out.substr(0, 2000));
    const size_t first = out.find(spin), last = out.rfind(spin);
    REQUIRE(first != std::string::npos);
    CHECK(out.compare(first + spin.size(), 7, "300000'") == 0);  // as started: libgomp's default
    CHECK(last != first);                                          // restarted once...
    CHECK(out.compare(last + spin.size(), 2, "0'") == 0);          // ...with PASSIVE waiting
    REQUIRE(run(argv, log, {"OMP_DISPLAY_ENV=VERBOSE", "OMP_NUM_THREADS=1", "OMP_WAIT_POLICY=ACTIVE"}) == 0);
    out = read_file(log);
    CHECK(out.find(spin) == out.rfind(spin));  // no restart
    CHECK_THAT(out, FLAT_CONTAINS("OMP_WAIT_POLICY = 'ACTIVE'"));
  }
  for (const auto& [name, value] : saved) setenv(name.c_str(), value.c_str(), 1);
}

TEST_CASE("bad inputs: exit code and the words of the message, before any work", "[cli]") {
  check_cases({
      // usage errors (2)
      {"synth_size", "flat_synth", {"--out", "{R}/s1", "--size", "16by24"}, 2, {"--size", "HxW"}},
      {"synth_frames", "flat_synth", {"--out", "{R}/s1", "--frames", "0"}, 2, {"--frames"}},
      {"synth_threads", "flat_synth", {"--out", "{R}/s1", "--threads", "-1"}, 2, {"--threads"}},
      {"latents_threads", "flat_latents", {"--scenes", "{SYNTH}", "--random-weights", "--threads", "x"}, 2,
       {"--threads"}},
      {"latents_window", "flat_latents", {"--scenes", "{SYNTH}", "--random-weights", "--window", "4"}, 2, {"1+4k"}},
      {"latents_no_weights", "flat_latents", {"--scenes", "{SYNTH}"}, 2, {"--random-weights"}},
      {"latents_size", "flat_latents", {"--scenes", "{SYNTH}", "--random-weights", "--size", "20x20"}, 2,
       {"multiples of 8"}},
      {"latents_device", "flat_latents", {"--scenes", "{SYNTH}", "--random-weights", "--device", "gpu"}, 2,
       {"--device"}},
      {"latents_store", "flat_latents", {"--scenes", "{SYNTH}", "--random-weights", "--store", "float32"}, 2,
       {"--store"}},
      {"vae_mp4", "flat_vae", {"decode", "--random-weights", "--dim", "4", "--in", "{R}/latent.safetensors", "--out",
                               "{R}/video.mp4"}, 2, {".safetensors file or a folder"}},
      {"vae_encode_png", "flat_vae", {"encode", "--random-weights", "--dim", "4", "--in", "{R}/video.safetensors",
                                      "--out", "{R}/latent.png"}, 2, {"--out must be a .safetensors"}},
      {"vae_two_weights", "flat_vae", {"encode", "--in", "{R}/video.safetensors", "--out", "{R}/z.safetensors"}, 2,
       {"--vae FILE or --random-weights"}},
      {"import_no_frames_dir", "flat_import", {"re10k", "--in", "{R}/cams.txt", "--out", "{R}/re"}, 2,
       {"--frames-dir"}},
      {"bench_raster_size", "flat_bench", {"raster", "--size", "paper"}, 2, {"--size"}},
      {"train_log_level", "flat_train", {"--config", "{R}/capture/transforms.json", "--log-level", "loud"}, 2, {"--log-level"}},
      // runtime errors (1): wrong or meaningless input, refused with the file, key or figure
      {"latents_short", "flat_latents", {"--scenes", "{SYNTH}", "--random-weights", "--dim", "4", "--window", "21"},
       1, {"no scene has --window 21", "longest has 5"}},
      {"latents_no_scenes", "flat_latents", {"--scenes", "{R}/capture", "--random-weights"}, 1,
       {"no scene folders"}},
      {"vae_nan_weights", "flat_vae", {"encode", "--vae", "{R}/weights_nan.safetensors", "--in",
                                       "{R}/video.safetensors", "--out", "{R}/z_nan.safetensors"}, 1,
       {"weights_nan.safetensors", "encoder.conv1.weight", "non-finite"}},
      {"vae_u8_weights", "flat_vae", {"encode", "--vae", "{R}/weights_u8.safetensors", "--in",
                                      "{R}/video.safetensors", "--out", "{R}/z_u8.safetensors"}, 1,
       {"weights_u8.safetensors", "floating point"}},
      {"vae_int64_video", "flat_vae", {"encode", "--random-weights", "--dim", "4", "--in",
                                       "{R}/video_int64.safetensors", "--out", "{R}/z_i64.safetensors"}, 1,
       {"video_int64.safetensors", "Long", "floating point"}},
      {"vae_255_video", "flat_vae", {"encode", "--random-weights", "--dim", "4", "--in", "{R}/video_255.safetensors",
                                     "--out", "{R}/z_255.safetensors"}, 1, {"video_255.safetensors", "[-1,1]"}},
      {"vae_weights_dir_empty", "flat_vae", {"encode", "--vae", "{R}/capture/images", "--in",
                                             "{R}/video.safetensors", "--out", "{R}/z_dir.safetensors"}, 1,
       {"without a .safetensors file"}},
      {"synth_huge", "flat_synth", {"--out", "{R}/huge", "--size", "100000x100000", "--frames", "9"}, 1,
       {"needs", "GiB", "available"}},
      {"render_huge_ply", "flat_render", {"--triangles", "{R}/huge.ply", "--cameras", "{R}/cams_small.json", "--out",
                                          "{R}/render_huge_ply", "--device", "cpu"}, 1,
       {"huge.ply: element 'face'", "4000000000 faces", "bytes follow the header"}},
      {"render_huge_camera", "flat_render", {"--triangles", "{R}/huge.ply", "--cameras", "{R}/huge_cams.json",
                                             "--out", "{R}/render_huge_cam", "--device", "cpu"}, 1,
       {"huge.ply"}},
      {"vae_weights_folder", "flat_vae", {"encode", "--vae", "{R}/diffusers", "--in", "{R}/video.safetensors",
                                          "--out", "{R}/z_folder.safetensors"}, 1,
       {"diffusion_pytorch_model.safetensors", "non-finite"}},
      {"pack_not_scenes", "flat_pack", {"--scenes", "{R}/capture"}, 1, {"capture", "no scene folders"}},
  });
  // --device cuda without a GPU is refused by name; with one (the GPU machine) it renders.
  if (!torch::cuda::is_available())
    check_cases({{"render_no_cuda", "flat_render", {"--triangles", "{R}/one.ply", "--cameras", "{R}/cams_small.json",
                                                    "--out", "{R}/render_cuda", "--device", "cuda"}, 1, {"--device cuda"}}});
  // Nothing was left behind by the refused runs.
  const Fixtures& f = fixtures();
  CHECK_FALSE(fs::exists(f.root + "/z_nan.safetensors"));
  CHECK_FALSE(fs::exists(f.root + "/z_255.safetensors"));
  CHECK_FALSE(fs::exists(f.root + "/render_huge_ply"));
  CHECK_FALSE(fs::exists(f.root + "/huge/room_000000"));
}

TEST_CASE("flat_render refuses a camera size that cannot fit, with the figure", "[cli]") {
  const Fixtures& f = fixtures();
  // The fixtures' one-triangle PLY, rendered into two 300000x300000 views.
  auto r = tool("flat_render", {"--triangles", f.root + "/one.ply", "--cameras", f.root + "/huge_cams.json", "--out",
                                f.root + "/render_huge", "--device", "cpu"},
                f.root, "render_huge_cam_valid");
  INFO(r.output);
  CHECK(r.rc == 1);
  CHECK_THAT(r.output, FLAT_CONTAINS("300000x300000"));
  CHECK_THAT(r.output, FLAT_CONTAINS("GiB"));
  CHECK_THAT(r.output, !FLAT_CONTAINS("bad_alloc"));
  CHECK_FALSE(fs::exists(f.root + "/render_huge"));
}

TEST_CASE("flat_import: a failed import into an existing scene leaves it byte-identical", "[cli]") {
  if (!flat::image_io_available()) FLAT_SKIP("this build has no OpenImageIO: the capture's PNGs cannot be imported");
  const Fixtures& f = fixtures();
  const std::string d = fresh_dir("cli_import").string(), scene = d + "/scene";
  auto ok = tool("flat_import", {"transforms", "--in", f.capture, "--out", scene}, d, "good");
  INFO(ok.output);
  REQUIRE(ok.rc == 0);
  const auto before = snapshot(scene);
  REQUIRE(before.count("scene.json"));
  // Refused up front without --overwrite.
  auto refused = tool("flat_import", {"transforms", "--in", f.capture, "--out", scene}, d, "again");
  CHECK(refused.rc == 1);
  CHECK_THAT(refused.output, FLAT_CONTAINS("already exists"));
  CHECK_THAT(refused.output, FLAT_CONTAINS("--overwrite"));
  CHECK(snapshot(scene) == before);
  // With --overwrite, a truncated image midway: exit 1 naming it, the old scene as it was.
  auto bad = tool("flat_import", {"transforms", "--in", f.bad_capture, "--out", scene, "--overwrite"}, d, "bad");
  INFO(bad.output);
  CHECK(bad.rc == 1);
  CHECK_THAT(bad.output, FLAT_CONTAINS("2.png"));
  CHECK_THAT(bad.output, !FLAT_CONTAINS("done in"));  // progress never claims success for a failed loop
  CHECK(snapshot(scene) == before);
  for (const auto& e : fs::directory_iterator(d))
    CHECK(e.path().filename().string().find("incomplete") == std::string::npos);
  // A good --overwrite replaces it whole; the log lies beside the scene.
  CHECK(tool("flat_import", {"transforms", "--in", f.capture, "--out", scene, "--overwrite", "--max-side", "12"}, d,
             "replace")
            .rc == 0);
  CHECK(snapshot(scene) != before);
  CHECK(fs::exists(d + "/scene.log"));
}

TEST_CASE("flat_synth: a second batch never replaces the first one's scenes", "[cli]") {
  const std::string d = fresh_dir("cli_synth").string(), out = d + "/data";
  const std::vector<std::string> batch = {"--out", out, "--count", "1", "--frames", "5", "--size", "16x24"};
  REQUIRE(tool("flat_synth", batch, d, "first").rc == 0);
  // Latents of the first batch, which a replaced scene would orphan.
  REQUIRE(random_latents(out, d, "latents").rc == 0);
  const auto before = snapshot(out + "/room_000000");
  REQUIRE(before.count("latents_16x24_f5.safetensors"));
  auto again = tool("flat_synth", batch, d, "second");
  CHECK(again.rc == 1);
  CHECK_THAT(again.output, FLAT_CONTAINS("room_000000"));
  CHECK_THAT(again.output, FLAT_CONTAINS("--first-index"));
  CHECK(snapshot(out + "/room_000000") == before);
  // Continuing the numbering adds room_000001 beside it.
  auto more = batch;
  more.insert(more.end(), {"--first-index", "1", "--seed", "4"});
  CHECK(tool("flat_synth", more, d, "continue").rc == 0);
  CHECK(fs::exists(out + "/room_000001/scene.json"));
  CHECK(snapshot(out + "/room_000000") == before);
  // --overwrite replaces a scene whole: no stale file of the old one stays.
  write_text(out + "/room_000000/images/stale.png", "x");
  auto over = batch;
  over.push_back("--overwrite");
  CHECK(tool("flat_synth", over, d, "overwrite").rc == 0);
  CHECK_FALSE(fs::exists(out + "/room_000000/images/stale.png"));
  CHECK_FALSE(fs::exists(out + "/room_000000/latents_16x24_f5.safetensors"));
  CHECK(fs::exists(out + "/room_000000/scene.json"));
  CHECK(fs::exists(out + "/flat_synth.log"));
}

TEST_CASE("flat_vae decode: an existing frame folder is kept unless --overwrite, then replaced whole", "[cli]") {
  if (!flat::image_io_available()) FLAT_SKIP("this build has no OpenImageIO: decoded frames are PNG files");
  const Fixtures& f = fixtures();
  const std::string d = fresh_dir("cli_vae").string(), frames = d + "/frames";
  const std::vector<std::string> args = {"decode", "--random-weights", "--dim", "4", "--in", f.latent, "--out", frames};
  auto first = tool("flat_vae", args, d, "first");
  INFO(first.output);
  REQUIRE(first.rc == 0);
  write_text(frames + "/frame_0099.png", "stale");
  const auto before = snapshot(frames);
  auto again = tool("flat_vae", args, d, "again");
  CHECK(again.rc == 1);
  CHECK_THAT(again.output, FLAT_CONTAINS("already exists"));
  CHECK(snapshot(frames) == before);
  auto over = args;
  over.push_back("--overwrite");
  CHECK(tool("flat_vae", over, d, "overwrite").rc == 0);
  CHECK_FALSE(fs::exists(frames + "/frame_0099.png"));
  CHECK(fs::exists(frames + "/frame_0004.png"));  // 1 + 4 (T'-1) frames of T' = 2
  // A file output too: refused, byte-identical.
  const std::string z = d + "/z.safetensors";
  const std::vector<std::string> enc = {"encode", "--random-weights", "--dim", "4", "--in", f.video_ok, "--out", z};
  REQUIRE(tool("flat_vae", enc, d, "encode").rc == 0);
  const auto z_before = snapshot(d)["z.safetensors"];
  CHECK(tool("flat_vae", enc, d, "encode_again").rc == 1);
  CHECK(snapshot(d)["z.safetensors"] == z_before);
}

TEST_CASE("flat_train: a run folder that holds a run is refused and left byte-identical", "[cli]") {
  const Fixtures& f = fixtures();
  const std::string d = fresh_dir("cli_train").string(), run_dir = d + "/run";
  write_text(run_dir + "/config.yaml", "steps: 7\n");
  write_text(run_dir + "/metrics/train.jsonl", "{\"step\": 1, \"loss\": 0.5}\n");
  write_text(run_dir + "/renders/val_step_1.png", "png");
  const auto before = snapshot(run_dir);
  write_text(d + "/config.yaml", "run_dir: " + run_dir + "\nsteps: 2\ndevice: cpu\nloss: {lambda_perc: 0}\n" +
                                     "data: {datasets: [{root: " + f.synth +
                                     "}], height: 16, width: 24, input_frames: 5, target_views: 2, latents: true}\n");
  auto r = tool("flat_train", {"--config", d + "/config.yaml"}, d, "train");
  INFO(r.output);
  CHECK(r.rc == 1);
  CHECK_THAT(r.output, FLAT_CONTAINS("already holds a run"));
  CHECK(snapshot(run_dir) == before);
  // --set of a boolean key is parsed as YAML and checked: a message naming the key, never a stack trace.
  auto s = tool("flat_train", {"--config", d + "/config.yaml", "--set", "data.latents=false", "--print-config"}, d,
                "set_bool");
  CHECK(s.rc == 1);
  CHECK_THAT(s.output, FLAT_CONTAINS("'data.latents' must be true"));
  CHECK_THAT(s.output, !FLAT_CONTAINS("Exception raised from"));
  // The config layers over the defaults: keys it leaves out keep theirs.
  auto p = tool("flat_train", {"--config", d + "/config.yaml", "--print-config"}, d, "print");
  CHECK(p.rc == 0);
  CHECK_THAT(p.output, FLAT_CONTAINS("steps: 2"));
  CHECK_THAT(p.output, FLAT_CONTAINS("optim:"));
}

TEST_CASE("flat_render and flat_bench raster: --device cpu works, an existing output is kept unless --overwrite",
          "[cli]") {
  const Fixtures& f = fixtures();
  const std::string d = fresh_dir("cli_render").string(), out = d + "/render";
  const std::vector<std::string> args = {"--triangles", f.root + "/one.ply", "--cameras", f.root + "/cams_small.json",
                                         "--out", out, "--device", "cpu"};
  auto first = tool("flat_render", args, d, "first");
  INFO(first.output);
  REQUIRE(first.rc == 0);
  const auto before = snapshot(out);
  REQUIRE(before.count("render.safetensors"));
  auto again = tool("flat_render", args, d, "again");
  CHECK(again.rc == 1);
  CHECK_THAT(again.output, FLAT_CONTAINS("already exists"));
  CHECK(snapshot(out) == before);
  if (flat::image_io_available()) {
    auto over = args;
    over.insert(over.end(), {"--overwrite", "--format", "png"});
    CHECK(tool("flat_render", over, d, "overwrite").rc == 0);
    CHECK_FALSE(fs::exists(out + "/render.safetensors"));
    CHECK(fs::exists(out + "/0000_rgb.png"));
  }
  CHECK(fs::exists(d + "/render.log"));
  // The raster benchmark on the CPU, on the same PLY and cameras.
  auto bench = tool("flat_bench", {"raster", "--device", "cpu", "--triangles", f.root + "/one.ply", "--cameras",
                                   f.root + "/cams_small.json", "--repeats", "1"},
                    d, "bench_raster_cpu");
  INFO(bench.output);
  CHECK(bench.rc == 0);
  CHECK_THAT(bench.output, FLAT_CONTAINS("forward+backward"));
}

// ---- issue #32: never destroy, never pass off wrong output -------------------------

namespace {

// A one-face triangle PLY (the format of docs/formats.md) with the given values.
std::string triangle_ply(float x0, float red, float opacity, float sigma) {
  std::string body;
  auto put = [&body](auto v) { body.append(reinterpret_cast<const char*>(&v), sizeof(v)); };
  for (float v : {x0, 0.f, 2.f, 0.5f, 0.f, 2.f, 0.f, 0.5f, 2.f}) put(v);
  put(uint8_t(3));
  for (int32_t i : {0, 1, 2}) put(i);
  for (float v : {red, 0.4f, 0.2f, opacity, sigma}) put(v);
  return "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
         "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
         "property float red\nproperty float green\nproperty float blue\nproperty float opacity\n"
         "property float sigma\nend_header\n" + body;
}

std::string cameras_with_c2w(const std::string& c2w) {
  return "{\"version\": 1, \"cameras\": [{\"width\": 8, \"height\": 8, \"intrinsics\": [1, 1, 0.5, 0.5], \"c2w\": " +
         c2w + "}]}";
}

}  // namespace

TEST_CASE("flat_latents, flat_pack: a failing scene is left byte-identical, reported, and does not stop the others",
          "[cli]") {
  const Fixtures& f = fixtures();
  const std::string d = fresh_dir("cli_inputs").string(), data = d + "/data";
  fs::copy(f.synth, data, fs::copy_options::recursive);
  const std::string scene_json = data + "/room_000000/scene.json";
  const std::string good_json = read_file(scene_json);
  fs::resize_file(scene_json, fs::file_size(scene_json) / 2);  // a scene.json cut short
  const auto before = snapshot(data + "/room_000000");
  auto latents = random_latents(data, d, "latents_bad");
  INFO(latents.output);
  CHECK(latents.rc == 1);
  CHECK_THAT(latents.output, FLAT_CONTAINS("scene.json"));
  CHECK(snapshot(data + "/room_000000") == before);
  // The report names the scene and why.
  CHECK_THAT(read_file(data + "/flat_latents_report.json"), FLAT_CONTAINS("room_000000"));
  CHECK_THAT(read_file(data + "/flat_latents_report.json"), FLAT_CONTAINS("scene.json"));
  auto pack = tool("flat_pack", {"--scenes", data}, d, "pack_bad");
  INFO(pack.output);
  CHECK(pack.rc == 1);
  CHECK(snapshot(data + "/room_000000") == before);
  if (flat::image_io_available()) {
    // A frame cut short, found only while encoding: the scene is not touched.
    write_text(scene_json, good_json);
    std::string png;
    for (const auto& e : fs::recursive_directory_iterator(data + "/room_000000"))
      if (e.path().extension() == ".png" && png.empty()) png = e.path().string();
    REQUIRE_FALSE(png.empty());
    fs::resize_file(png, 40);
    const auto before_frames = snapshot(data + "/room_000000");
    auto mid = random_latents(data, d, "latents_bad_frame");
    INFO(mid.output);
    CHECK(mid.rc == 1);
    CHECK(snapshot(data + "/room_000000") == before_frames);
    // Two scenes, the first's frame cut short: the second is encoded and
    // committed all the same (one bad clip in 10,000 loses nothing else), the
    // bad one stays as it was, and the run ends with exit 1 naming it.
    const std::string two = d + "/two";
    fs::create_directories(two);
    fs::copy(data + "/room_000000", two + "/room_a", fs::copy_options::recursive);  // the bad frame
    fs::copy(f.synth + "/room_000000", two + "/room_b", fs::copy_options::recursive);
    const auto before_a = snapshot(two + "/room_a");
    auto second = random_latents(two, d, "latents_first_bad");
    INFO(second.output);
    CHECK(second.rc == 1);
    CHECK_THAT(second.output, FLAT_CONTAINS("room_a"));
    CHECK(snapshot(two + "/room_a") == before_a);  // no latent file, no staged file
    CHECK(fs::exists(two + "/room_b/latents_16x24_f5.safetensors"));
    CHECK_THAT(read_file(two + "/room_b/scene.json"), FLAT_CONTAINS("latent_sets"));
    const std::string report = read_file(two + "/flat_latents_report.json");
    CHECK_THAT(report, FLAT_CONTAINS("room_a"));
    CHECK_THAT(report, !FLAT_CONTAINS("room_b"));
  }
  // A run that succeeds leaves its log there, as docs/cli.md says.
  const std::string good = d + "/good";
  fs::copy(f.synth, good, fs::copy_options::recursive);
  auto ok = random_latents(good, d, "latents_ok");
  INFO(ok.output);
  CHECK(ok.rc == 0);
  CHECK_THAT(read_file(good + "/flat_latents.log"), FLAT_CONTAINS("1 set(s) encoded"));
  // A log that cannot be placed (here a folder of that name) does not fail a run whose work is done.
  const std::string blocked = d + "/blocked";
  fs::copy(f.synth, blocked, fs::copy_options::recursive);
  fs::create_directories(blocked + "/flat_latents.log");
  auto warned = random_latents(blocked, d, "latents_blocked_log");
  INFO(warned.output);
  CHECK(warned.rc == 0);
  CHECK_THAT(warned.output, FLAT_CONTAINS("cannot append the log there"));
}

TEST_CASE("flat_latents: latent sets by size and window; a new set leaves the others byte-identical", "[cli]") {
  const Fixtures& f = fixtures();
  const std::string d = fresh_dir("cli_latent_sets").string(), data = d + "/data";
  fs::create_directories(data);
  // Three 9-frame scenes.
  REQUIRE(tool("flat_synth", {"--out", data, "--count", "3", "--frames", "9", "--size", "16x24"}, d, "synth").rc == 0);
  (void)f;
  const std::vector<std::string> rnd = {"--random-weights", "--dim", "4", "--seed", "1"};
  auto args = [&](std::vector<std::string> a) {
    a.insert(a.begin(), {"--scenes", data});
    a.insert(a.end(), rnd.begin(), rnd.end());
    return a;
  };
  const std::string room = data + "/room_000000";
  REQUIRE(tool("flat_latents", args({"--window", "5", "--size", "16x24"}), d, "first").rc == 0);
  const std::string first_file = room + "/latents_16x24_f5.safetensors";
  REQUIRE(fs::exists(first_file));
  const std::string first_bytes = read_file(first_file);
  // A second set (9-frame windows at 8x16) is added beside it: the first file is untouched.
  auto second = tool("flat_latents", args({"--window", "9", "--size", "8x16"}), d, "second");
  INFO(second.output);
  REQUIRE(second.rc == 0);
  CHECK(read_file(first_file) == first_bytes);
  CHECK(fs::exists(room + "/latents_8x16_f9.safetensors"));
  auto scene = flat::data::read_scene(room);
  REQUIRE(scene.latent_sets.size() == 2);
  CHECK(flat::data::latent_set_list(scene) == "8x16_f9, 16x24_f5");
  // The same set again, made the same way: nothing to do, nothing touched.
  const auto all_before = snapshot(room);
  auto again = tool("flat_latents", args({"--window", "5", "--size", "16x24"}), d, "again");
  INFO(again.output);
  CHECK(again.rc == 0);
  CHECK_THAT(again.output, FLAT_CONTAINS("3 already present"));
  CHECK(snapshot(room) == all_before);
  // Made another way (another seed): refused per scene without --overwrite, named, nothing touched.
  auto other = tool("flat_latents", {"--scenes", data, "--random-weights", "--dim", "4", "--seed", "2", "--window", "5",
                                     "--size", "16x24"},
                    d, "other_seed");
  INFO(other.output);
  CHECK(other.rc == 1);
  CHECK_THAT(other.output, FLAT_CONTAINS("--overwrite"));
  CHECK(snapshot(room) == all_before);
  // --overwrite replaces that set and leaves the other set's file as it was.
  const std::string nine_bytes = read_file(room + "/latents_8x16_f9.safetensors");
  auto over = tool("flat_latents", {"--scenes", data, "--random-weights", "--dim", "4", "--seed", "2", "--window", "5",
                                    "--size", "16x24", "--overwrite"},
                   d, "overwrite");
  INFO(over.output);
  CHECK(over.rc == 0);
  CHECK(read_file(first_file) != first_bytes);
  CHECK(read_file(room + "/latents_8x16_f9.safetensors") == nine_bytes);
  // Shards: 0/2 and 1/2 take disjoint scenes that together are all of them.
  const std::string sharded = d + "/sharded";
  fs::create_directories(sharded);
  REQUIRE(tool("flat_synth", {"--out", sharded, "--count", "3", "--frames", "5", "--size", "16x24"}, d, "synth2").rc ==
          0);
  auto s0 = random_latents(sharded, d, "shard0", {"--shard", "0/2"});
  INFO(s0.output);
  CHECK(s0.rc == 0);
  CHECK(fs::exists(sharded + "/room_000000/latents_16x24_f5.safetensors"));
  CHECK_FALSE(fs::exists(sharded + "/room_000001/latents_16x24_f5.safetensors"));
  CHECK(fs::exists(sharded + "/room_000002/latents_16x24_f5.safetensors"));
  CHECK(fs::exists(sharded + "/flat_latents_report.shard-0-of-2.json"));
  auto s1 = random_latents(sharded, d, "shard1", {"--shard", "1/2"});
  CHECK(s1.rc == 0);
  CHECK(fs::exists(sharded + "/room_000001/latents_16x24_f5.safetensors"));
  CHECK(tool("flat_latents", {"--scenes", sharded, "--random-weights", "--dim", "4", "--shard", "2/2"}, d, "shard_bad")
            .rc == 2);
}

TEST_CASE("flat_eval: --out-table never replaces a file without --overwrite; bad flags are usage errors", "[cli]") {
  const std::string d = fresh_dir("cli_eval").string();
  write_text(d + "/table.md", "my own table\n");
  auto r = tool("flat_eval", {"--compare", d + "/a", d + "/b", "--out-table", d + "/table.md"}, d, "out_table");
  INFO(r.output);
  CHECK(r.rc == 1);
  CHECK_THAT(r.output, FLAT_CONTAINS(d + "/table.md: already exists"));
  CHECK(read_file(d + "/table.md") == "my own table\n");
  for (const auto& bad : std::vector<std::vector<std::string>>{
           {"--views", "foo"}, {"--ssim", "ms"}, {"--max-views", "-1"}, {"--window-index", "-2"},
           {"--size", "100000x100000"}}) {
    std::vector<std::string> args = {"--model", d + "/m", "--scenes", d + "/s", "--out", d + "/out"};
    args.insert(args.end(), bad.begin(), bad.end());
    auto u = tool("flat_eval", args, d, "usage" + bad[0]);
    INFO(bad[0] << " " << bad[1] << ": " << u.output);
    CHECK(u.rc == 2);
    CHECK_THAT(u.output, FLAT_CONTAINS(bad[0]));
  }
  CHECK_FALSE(fs::exists(d + "/out"));
}

TEST_CASE("flat_render: bad cameras, backgrounds and triangle values are refused, naming the file", "[cli]") {
  const Fixtures& f = fixtures();
  const std::string d = fresh_dir("cli_render_bad").string();
  const std::string ply = f.root + "/one.ply", cams = f.root + "/cams_small.json";
  // --background: not numbers, outside [0,1], NaN: usage errors, nothing written.
  for (const std::string bg : {"abc", "2,0,0", "nan,0,0", "0.5,0.5", "0,0,1.5"}) {
    auto r = tool("flat_render", {"--triangles", ply, "--cameras", cams, "--out", d + "/bg", "--background", bg,
                                  "--device", "cpu"},
                  d, "bg");
    INFO(bg << ": " << r.output);
    CHECK(r.rc == 2);
    CHECK_THAT(r.output, FLAT_CONTAINS("--background"));
    CHECK_FALSE(fs::exists(d + "/bg"));
  }
  // c2w: a 3x4 matrix or a last row other than 0 0 0 1 is no rigid pose.
  write_text(d + "/cams_3x4.json", cameras_with_c2w("[[1,0,0,0],[0,1,0,0],[0,0,1,0]]"));
  write_text(d + "/cams_row.json", cameras_with_c2w("[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,1,2]]"));
  for (const std::string c : {"cams_3x4.json", "cams_row.json"}) {
    auto r = tool("flat_render", {"--triangles", ply, "--cameras", d + "/" + c, "--out", d + "/cam", "--device", "cpu"},
                  d, c);
    INFO(r.output);
    CHECK(r.rc == 1);
    CHECK_THAT(r.output, FLAT_CONTAINS(c));
    CHECK_THAT(r.output, FLAT_CONTAINS("'c2w'"));
    CHECK_FALSE(fs::exists(d + "/cam"));
  }
  // Triangle values outside the format: the message names the PLY file.
  struct Bad {
    std::string name, ply, words;
  };
  for (const auto& b : {Bad{"nan_vertex", triangle_ply(NAN, 0.8f, 0.9f, 1.f), "a non-finite vertex"},
                        Bad{"negative_sigma", triangle_ply(0.f, 0.8f, 0.9f, -1.f), "sigma"},
                        Bad{"opacity_1.5", triangle_ply(0.f, 0.8f, 1.5f, 1.f), "opacity outside [0, 1]"},
                        Bad{"inf_colour", triangle_ply(0.f, INFINITY, 0.9f, 1.f), "a non-finite colour"}}) {
    const std::string file = d + "/" + b.name + ".ply";
    write_text(file, b.ply);
    auto r = tool("flat_render", {"--triangles", file, "--cameras", cams, "--out", d + "/tri", "--device", "cpu"}, d,
                  b.name);
    INFO(b.name << ": " << r.output);
    CHECK(r.rc == 1);
    CHECK_THAT(r.output, FLAT_CONTAINS(file + ": 1 face(s) with " + b.words));
    CHECK_FALSE(fs::exists(d + "/tri"));
  }
  // The good PLY still renders (the helper writes a valid one).
  write_text(d + "/good.ply", triangle_ply(0.f, 0.8f, 0.9f, 1.f));
  CHECK(tool("flat_render", {"--triangles", d + "/good.ply", "--cameras", cams, "--out", d + "/ok", "--device", "cpu"},
             d, "good")
            .rc == 0);
}

TEST_CASE("flat_infer: contradictory inputs and an unknown --novel are usage errors", "[cli]") {
  const Fixtures& f = fixtures();
  const std::string d = fresh_dir("cli_infer_usage").string();
  const std::vector<std::string> base = {"--model", d + "/no_model", "--out", d + "/out"};
  auto with = [&](std::vector<std::string> extra) {
    auto a = base;
    a.insert(a.end(), extra.begin(), extra.end());
    return a;
  };
  auto neither = tool("flat_infer", base, d, "neither");
  CHECK(neither.rc == 2);
  CHECK_THAT(neither.output, FLAT_CONTAINS("exactly one of --scene"));
  auto both = tool("flat_infer", with({"--scene", f.synth + "/room_000000", "--latents", f.latent, "--cameras",
                                       f.root + "/cams_small.json"}),
                   d, "both");
  CHECK(both.rc == 2);
  auto novel = tool("flat_infer", with({"--scene", f.synth + "/room_000000", "--novel", "circle"}), d, "novel");
  CHECK(novel.rc == 2);
  CHECK_THAT(novel.output, FLAT_CONTAINS("orbit | dolly | none"));
  CHECK_FALSE(fs::exists(d + "/out"));
  // --help does not pass off bf16 as what a CPU run computes in.
  const auto help = tool("flat_infer", {"--help"}, d, "help").output;
  CHECK_THAT(help, FLAT_CONTAINS("on the CPU the run is fp32"));
  // A staging folder left by a killed run is explained where the user looks.
  CHECK_THAT(help, FLAT_CONTAINS("the next run on the same --out removes"));
}

TEST_CASE("flat_mesh: a missing source is a usage error; a soup without a scene names what is missing", "[cli]") {
  const Fixtures& f = fixtures();
  const std::string d = fresh_dir("cli_mesh").string();
  auto nothing = tool("flat_mesh", {"--from", d + "/none", "--out", d + "/out"}, d, "none");
  CHECK(nothing.rc == 2);
  CHECK_THAT(nothing.output, FLAT_CONTAINS("no such file or folder"));
  CHECK(tool("flat_mesh", {"--out", d + "/out"}, d, "no_from").rc == 2);
  // A soup PLY alone: which frames to fit is unknown.
  auto bare = tool("flat_mesh", {"--from", f.root + "/one.ply", "--out", d + "/out"}, d, "bare");
  CHECK(bare.rc == 1);
  CHECK_THAT(bare.output, FLAT_CONTAINS("--scene"));
  // A scene without latents has no window to fit.
  auto no_latents =
      tool("flat_mesh", {"--from", f.root + "/one.ply", "--scene", f.synth + "/room_000000", "--out", d + "/out"}, d,
           "no_latents");
  CHECK(no_latents.rc == 1);
  CHECK_THAT(no_latents.output, FLAT_CONTAINS("no latents"));
  CHECK_FALSE(fs::exists(d + "/out"));
  CHECK_THAT(tool("flat_mesh", {"--help"}, d, "help").output, FLAT_CONTAINS("paper: 250"));
  // The conversion is chosen by name; another name is a usage error naming the flag.
  const auto help = tool("flat_mesh", {"--help"}, d, "help_conversion").output;
  CHECK_THAT(help, FLAT_CONTAINS("--conversion") && FLAT_CONTAINS("stitch"));
  auto bad = tool("flat_mesh", {"--from", f.root + "/one.ply", "--out", d + "/out", "--conversion", "poisson"}, d,
                  "bad_conversion");
  CHECK(bad.rc == 2);
  CHECK_THAT(bad.output, FLAT_CONTAINS("--conversion"));
}

TEST_CASE("flat_import transforms: a frame whose rotation is all zero is refused, naming the frame", "[cli]") {
  if (!flat::image_io_available()) FLAT_SKIP("this build has no OpenImageIO: the capture's PNGs cannot be imported");
  const Fixtures& f = fixtures();
  const std::string d = fresh_dir("cli_import_zero").string(), capture = d + "/capture";
  fs::copy(f.capture, capture, fs::copy_options::recursive);
  std::string json = read_file(capture + "/transforms.json");
  const std::string second = "[[1,0,0,0.1";
  const auto at = json.find(second);
  REQUIRE(at != std::string::npos);
  // Frame 1: [[0,0,0,0.1],[0,0,0,0],[0,0,0,0],[0,0,0,1]].
  const auto end = json.find("]]", at);
  json.replace(at, end + 2 - at, "[[0,0,0,0.1],[0,0,0,0],[0,0,0,0],[0,0,0,1]]");
  write_text(capture + "/transforms.json", json);
  auto r = tool("flat_import", {"transforms", "--in", capture, "--out", d + "/scene"}, d, "zero");
  INFO(r.output);
  CHECK(r.rc == 1);
  CHECK_THAT(r.output, FLAT_CONTAINS("images/1.png"));
  CHECK_THAT(r.output, FLAT_CONTAINS("rotation is degenerate"));
  CHECK_FALSE(fs::exists(d + "/scene"));
}

TEST_CASE("an output path under a file names the path and what is wrong, never a bare filesystem error", "[cli]") {
  const Fixtures& f = fixtures();
  const std::string d = fresh_dir("cli_out_file").string();
  write_text(d + "/afile", "x");
  auto synth = tool("flat_synth", {"--out", d + "/afile/synth", "--count", "1", "--frames", "5", "--size", "16x24"},
                    d, "synth");
  INFO(synth.output);
  CHECK(synth.rc == 1);
  CHECK_THAT(synth.output, FLAT_CONTAINS(d + "/afile/synth"));
  CHECK_THAT(synth.output, FLAT_CONTAINS("Not a directory"));
  CHECK_THAT(synth.output, !FLAT_CONTAINS("unexpected error"));
  auto render = tool("flat_render", {"--triangles", f.root + "/one.ply", "--cameras", f.root + "/cams_small.json",
                                     "--out", d + "/afile/render", "--device", "cpu"},
                     d, "render");
  INFO(render.output);
  CHECK(render.rc == 1);
  CHECK_THAT(render.output, FLAT_CONTAINS(d + "/afile/render"));
  CHECK_THAT(render.output, !FLAT_CONTAINS("unexpected error"));
  CHECK(read_file(d + "/afile") == "x");

  // A place the tool may not write: a read-only folder (root ignores the mode
  // bits, so as root /sys, where even root may not create a folder).
  std::string denied = d + "/readonly";
  fs::create_directories(denied);
  fs::permissions(denied, fs::perms::owner_read | fs::perms::owner_exec);
  if (::geteuid() == 0) denied = "/sys";
  std::error_code ec;
  if (fs::create_directory(denied + "/flat_probe", ec)) {
    fs::remove(denied + "/flat_probe");
    WARN("no unwritable folder to test with here");
  } else {
    for (const auto& [name, args] :
         std::vector<std::pair<std::string, std::vector<std::string>>>{
             {"synth", {"--out", denied + "/flat_synth_out", "--count", "1", "--frames", "5", "--size", "16x24"}},
             {"render", {"--triangles", f.root + "/one.ply", "--cameras", f.root + "/cams_small.json", "--out",
                         denied + "/flat_render_out", "--device", "cpu"}}}) {
      auto r = tool("flat_" + name, args, d, name + "_denied");
      INFO(r.output);
      CHECK(r.rc == 1);
      CHECK_THAT(r.output, FLAT_CONTAINS(denied + "/flat_" + name + "_out"));
      const bool says_why = r.output.find("ermission denied") != std::string::npos ||
                            r.output.find("Operation not permitted") != std::string::npos ||
                            r.output.find("Read-only file system") != std::string::npos;
      CHECK(says_why);
      CHECK_THAT(r.output, !FLAT_CONTAINS("unexpected error"));
    }
  }
  fs::permissions(d + "/readonly", fs::perms::owner_all);
}

TEST_CASE("never destroy: every tool against an existing folder of user files, refused, failing and succeeding",
          "[cli]") {
  const Fixtures& f = fixtures();
  const std::string d = fresh_dir("cli_never_destroy").string();
  // The user's own files where a tool is told to write.
  auto user_folder = [](const std::string& dir) {
    write_text(dir + "/thesis.tex", "my thesis\n");
    write_text(dir + "/data/table.csv", "1,2,3\n");
    return snapshot(dir);
  };
  flat::save_safetensors(d + "/latent_bad.safetensors", {{"latent", torch::randn({1, 5, 2, 2, 3})}});
  write_text(d + "/nan.ply", triangle_ply(NAN, 0.8f, 0.9f, 1.f));
  struct Run {
    std::string name, program;
    std::vector<std::string> args;  // {OUT}: the target
  };
  struct ToolCase {
    Run refused, failing, succeeding;  // without --overwrite; with it on a bad input; with it on a good one
    std::string written;               // a file only the succeeding run writes in the target
  };
  auto with_out = [](std::vector<std::string> args, const std::string& out) {
    for (auto& a : args)
      if (a == "{OUT}") a = out;
    return args;
  };
  const std::vector<ToolCase> cases = {
      {{"render", "flat_render", {"--triangles", f.root + "/one.ply", "--cameras", f.root + "/cams_small.json", "--out",
                                  "{OUT}", "--device", "cpu"}},
       {"render", "flat_render", {"--triangles", d + "/nan.ply", "--cameras", f.root + "/cams_small.json", "--out",
                                  "{OUT}", "--device", "cpu", "--overwrite"}},
       {"render", "flat_render", {"--triangles", f.root + "/one.ply", "--cameras", f.root + "/cams_small.json", "--out",
                                  "{OUT}", "--device", "cpu", "--overwrite"}},
       "render.safetensors"},
      {{"vae", "flat_vae", {"decode", "--random-weights", "--dim", "4", "--in", f.latent, "--out", "{OUT}"}},
       {"vae", "flat_vae", {"decode", "--random-weights", "--dim", "4", "--in", d + "/latent_bad.safetensors", "--out",
                            "{OUT}", "--overwrite"}},
       {"vae", "flat_vae", {"decode", "--random-weights", "--dim", "4", "--in", f.latent, "--out", "{OUT}",
                            "--overwrite"}},
       "frame_0000.png"},
  };
  for (const auto& c : cases) {
    if (c.succeeding.program == "flat_vae" && !flat::image_io_available()) continue;  // PNG frames
    const std::string out = d + "/" + c.refused.name;
    const auto before = user_folder(out);
    auto refused = tool(c.refused.program, with_out(c.refused.args, out), d, c.refused.name + "_refused");
    INFO(c.refused.name << " refused: " << refused.output);
    CHECK(refused.rc == 1);
    CHECK_THAT(refused.output, FLAT_CONTAINS("--overwrite"));
    CHECK(snapshot(out) == before);
    auto failing = tool(c.failing.program, with_out(c.failing.args, out), d, c.failing.name + "_failing");
    INFO(c.failing.name << " failing: " << failing.output);
    CHECK(failing.rc == 1);
    CHECK(snapshot(out) == before);
    auto ok = tool(c.succeeding.program, with_out(c.succeeding.args, out), d, c.succeeding.name + "_ok");
    INFO(c.succeeding.name << " succeeding: " << ok.output);
    CHECK(ok.rc == 0);
    const auto after = snapshot(out);
    CHECK(after.count(c.written) == 1);
    CHECK(after.count("thesis.tex") == 0);  // replaced whole, as asked
    for (const auto& e : fs::directory_iterator(d))
      CHECK(e.path().filename().string().find(".incomplete-") == std::string::npos);
  }
  // flat_synth writes scene folders into --out: the user's files beside them stay as they were.
  const std::string synth = d + "/synth";
  const auto synth_before = user_folder(synth);
  REQUIRE(tool("flat_synth", {"--out", synth, "--count", "1", "--frames", "5", "--size", "16x24"}, d, "synth").rc == 0);
  auto synth_after = snapshot(synth);
  for (const auto& [file, bytes] : synth_before) CHECK(synth_after[file] == bytes);
  // flat_vae encode into an existing file: refused, and a failing --overwrite keeps it.
  write_text(d + "/z.safetensors", "the user's own file");
  CHECK(tool("flat_vae", {"encode", "--random-weights", "--dim", "4", "--in", f.video_ok, "--out", d + "/z.safetensors"},
             d, "encode_refused")
            .rc == 1);
  CHECK(tool("flat_vae", {"encode", "--random-weights", "--dim", "4", "--in", f.root + "/video_int64.safetensors",
                          "--out", d + "/z.safetensors", "--overwrite"},
             d, "encode_failing")
            .rc == 1);
  CHECK(read_file(d + "/z.safetensors") == "the user's own file");
}

TEST_CASE("flat_bench: a size that cannot fit is one line, not a stack trace; loader cleans its temp folder",
          "[cli]") {
  check_cases({{"bench_decoder_huge", "flat_bench", {"decoder", "--device", "cpu", "--latent-frames", "1", "--height",
                                                     "100000", "--width", "100000", "--dim", "4", "--repeats", "1",
                                                     "--warmup", "0", "--mode", "full"},
                1, {"100000x100000", "GiB on cpu", "available"}}});  // refused before allocating (issue #45)
  // The loader bench fails after synthesising its scenes (a window longer than they are): its temporary folder goes.
  const std::string d = fresh_dir("cli_bench_loader").string(), tmp = d + "/tmp";
  fs::create_directories(tmp);
  const int rc = run({binary("flat_bench"), "loader", "--count", "1", "--scene-frames", "5", "--source-size", "16x24",
                      "--size", "16x24", "--window", "9", "--targets", "1", "--batch", "1", "--workers", "0",
                      "--batches", "1", "--warmup", "0", "--mode", "files"},
                     d + "/loader.txt", {"TMPDIR=" + tmp, "OMP_NUM_THREADS=1"});
  INFO(read_file(d + "/loader.txt"));
  CHECK(rc == 1);
  CHECK_THAT(read_file(d + "/loader.txt"), FLAT_CONTAINS("synthesised 1 scenes"));
  CHECK(fs::is_empty(tmp));
}

TEST_CASE("flat_synth: a huge --count says what it does at once", "[cli]") {
  const std::string d = fresh_dir("cli_synth_many").string();
  auto child = spawn({binary("flat_synth"), "--out", d + "/data", "--count", "100000000", "--frames", "5", "--size",
                      "16x24", "--first-index", "3"},
                     d + "/log.txt", {"OMP_NUM_THREADS=1"});
  REQUIRE(child.pid > 0);
  // The first line within seconds (the old code looked up 10^8 scene names first, for minutes).
  const bool spoke = wait_until([&] { return read_file(d + "/log.txt").find("100000000 room scene(s)") != std::string::npos; }, 20);
  kill(child.pid, SIGKILL);
  wait_for(child);
  INFO(read_file(d + "/log.txt"));
  CHECK(spoke);
}

TEST_CASE("flat_bench decoder and raster say what they time before the first run", "[cli]") {
  const Fixtures& f = fixtures();
  const std::string d = fresh_dir("cli_bench_says").string();
  auto dec = tool("flat_bench", {"decoder", "--device", "cpu", "--latent-frames", "1", "--height", "2", "--width", "2",
                                 "--dim", "4", "--repeats", "1", "--warmup", "1", "--mode", "full", "--precision", "fp32"},
                  d, "decoder");
  INFO(dec.output);
  CHECK(dec.rc == 0);
  const auto plan = dec.output.find("1 warm-up + 1 timed run(s) on cpu"), result = dec.output.find("median");
  CHECK(plan != std::string::npos);
  CHECK(plan < result);
  auto ras = tool("flat_bench", {"raster", "--device", "cpu", "--triangles", f.root + "/one.ply", "--cameras",
                                 f.root + "/cams_small.json", "--repeats", "1"},
                  d, "raster");
  INFO(ras.output);
  CHECK(ras.rc == 0);
  CHECK(ras.output.find("2 warm-up + 1 timed forward+backward run(s)") < ras.output.find("forward+backward 0") );
}

TEST_CASE("flat_import batch: a failed clip makes exit 1 after the others land; a rerun resumes", "[cli][import_batch]") {
  if (!flat::image_io_available()) FLAT_SKIP("this build has no OpenImageIO: the clips' frames are PNG");
  const Fixtures& f = fixtures();
  const std::string d = fresh_dir("cli_import_batch").string();
  const std::string cams = d + "/cams", frames = d + "/frames", out = d + "/out";
  // RealEstate10K clips of two frames (identity poses shifted along x); "bad" has a truncated line.
  auto clip = [&](const std::string& name, bool truncated) {
    std::string text = "https://www.youtube.com/watch?v=" + name + "\n";
    for (int i = 0; i < 2; ++i) {
      const std::string ts = std::to_string(1000 + i);
      text += ts + (truncated && i == 1 ? " 0.8 0.9\n" : " 0.8 0.9 0.5 0.5 0 0 1 0 0 " + std::to_string(i) +
                                                             " 0 1 0 0 0 0 1 0\n");
      flat::write_image(frames + "/" + name + "/" + ts + ".png", torch::rand({3, 8, 12}));
    }
    write_text(cams + "/" + name + ".txt", text);
  };
  clip("good1", false);
  clip("good2", false);
  clip("bad", true);
  auto r = tool("flat_import", {"re10k", "--in", cams, "--frames-dir", frames, "--out", out, "--jobs", "2"}, d, "batch");
  INFO(r.output);
  CHECK(r.rc == 1);
  CHECK_THAT(r.output, FLAT_CONTAINS("bad.txt: line 3"));
  CHECK_THAT(r.output, FLAT_CONTAINS("import_summary.json"));
  CHECK(fs::exists(out + "/good1/scene.json"));
  CHECK(fs::exists(out + "/good2/scene.json"));
  CHECK_FALSE(fs::exists(out + "/bad"));
  CHECK_THAT(read_file(out + "/import_summary.json"), FLAT_CONTAINS("\"failed\": 1"));
  CHECK(fs::exists(out + "/flat_import.log"));
  // The bad clip repaired: the rerun imports it alone and exits 0.
  clip("bad", false);
  auto again = tool("flat_import", {"re10k", "--in", cams, "--frames-dir", frames, "--out", out}, d, "batch_again");
  INFO(again.output);
  CHECK(again.rc == 0);
  CHECK_THAT(again.output, FLAT_CONTAINS("1 imported, 2 already present, 0 failed"));
  CHECK(fs::exists(out + "/bad/scene.json"));
  // Batch-only and single-only flags are usage errors; --help names the summary and the exit codes.
  CHECK(tool("flat_import", {"re10k", "--in", cams, "--frames-dir", frames, "--out", out, "--name", "x"}, d,
             "batch_name")
            .rc == 2);
  CHECK(tool("flat_import", {"transforms", "--in", f.capture, "--out", d + "/one", "--jobs", "2"}, d, "single_jobs")
            .rc == 2);
  auto help = tool("flat_import", {"--help"}, d, "help");
  CHECK_THAT(help.output, FLAT_CONTAINS("--jobs"));
  CHECK_THAT(help.output, FLAT_CONTAINS("import_summary.json"));
  CHECK_THAT(help.output, FLAT_CONTAINS("at least one clip failed"));
}
