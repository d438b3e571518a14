// docs/own_videos.md ("Train on your own videos") as a user runs it:
// scripts/run_guide.sh runs its ```bash blocks in order, here as the rehearsal
// the guide describes (tiny synthetic RealEstate10K clips and DL3DV scenes from
// flat_synth --format, one corrupt clip of each, configs/tiny on the CPU,
// random-weight latents, a few steps per stage). And a fast check that every
// --flag the guide gives a flat_ tool is one that tool's --help names.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <sstream>

#include "flat/data/scene.h"
#include "flat/eval/evaluation_report.h"
#include "train_fixtures.h"

namespace fs = std::filesystem;
using namespace flat::test;

namespace {

const std::string kGuide = std::string(FLAT_SOURCE_DIR) + "/docs/own_videos.md";
const std::string kRunGuide = std::string(FLAT_SOURCE_DIR) + "/scripts/run_guide.sh";

// One command of a flat_ tool in a fenced block: the tool, its first word
// after the tool (a subcommand such as `re10k`, or ""), its --flags (without
// any =value), and where it is.
struct ToolCommand {
  std::string tool, subcommand, where;
  std::vector<std::string> flags;
};

// Shell words of one logical line (continuations joined): quotes removed,
// operators (; & | && || ( )) as words of their own, a comment dropped.
std::vector<std::string> shell_words(const std::string& line) {
  std::vector<std::string> words;
  std::string word;
  bool have = false;
  char quote = 0;
  auto flush = [&] {
    if (have) words.push_back(word);
    word.clear();
    have = false;
  };
  for (size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quote) {
      if (c == quote) quote = 0;
      else word += c;
      continue;
    }
    if (c == '\'' || c == '"') {
      quote = c;
      have = true;
    } else if (c == '\\' && i + 1 < line.size()) {
      word += line[++i];
      have = true;
    } else if (c == '#' && !have) {
      break;
    } else if (c == ' ' || c == '\t') {
      flush();
    } else if (c == ';' || c == '&' || c == '|' || c == '(' || c == ')') {
      if (c == '(' && have && !word.empty() && word.back() == '$') {  // $( ... ): part of the word
        word += c;
        continue;
      }
      flush();
      std::string op(1, c);
      if ((c == '&' || c == '|') && i + 1 < line.size() && line[i + 1] == c) op += line[++i];
      words.push_back(op);
    } else {
      word += c;
      have = true;
    }
  }
  flush();
  return words;
}

bool is_operator(const std::string& w) {
  return w == ";" || w == "&" || w == "|" || w == "&&" || w == "||" || w == "(" || w == ")";
}

// The logical lines (continuations joined) of every fenced block of
// `markdown`, ```bash and ```text alike: {first line number, text}.
std::vector<std::pair<int, std::string>> code_lines(const std::string& markdown) {
  std::vector<std::pair<int, std::string>> out;
  std::istringstream in(markdown);
  bool inside = false;
  std::string logical;
  int number = 0, first = 0;
  for (std::string line; std::getline(in, line);) {
    ++number;
    if (line.rfind("```", 0) == 0) {
      inside = !inside;
      logical.clear();
      continue;
    }
    if (!inside) continue;
    if (logical.empty()) first = number;
    if (!line.empty() && line.back() == '\\') {
      logical += line.substr(0, line.size() - 1) + " ";
      continue;
    }
    out.emplace_back(first, logical + line);
    logical.clear();
  }
  return out;
}

const std::regex kAssignment("^([A-Za-z_][A-Za-z0-9_]*)=(.*)$");
const std::regex kDefault("^\\$\\{([A-Za-z_][A-Za-z0-9_]*):?=(.*)\\}$");  // : "${NAME:=value}"
const std::regex kVariable("^\\$\\{?([A-Za-z_][A-Za-z0-9_]*)\\}?$");      // $NAME or ${NAME}, a whole word

// Every value the code blocks give each variable (NAME=value, ${NAME:=value}).
std::map<std::string, std::vector<std::string>> variable_values(const std::string& markdown) {
  std::map<std::string, std::vector<std::string>> out;
  for (const auto& [number, text] : code_lines(markdown))
    for (const auto& w : shell_words(text)) {
      std::smatch m;
      if (std::regex_match(w, m, kAssignment) || std::regex_match(w, m, kDefault)) out[m[1]].push_back(m[2]);
    }
  return out;
}

// Every flat_ command of every fenced block of `markdown`: a command starts a
// line or follows an operator, after shell keywords and NAME=value
// assignments. A word $NAME contributes the --flags of every value the
// blocks give NAME (VAE="--random-weights ...", EXTRA="--set ...").
std::vector<ToolCommand> tool_commands(const std::string& markdown, const std::string& label) {
  static const std::set<std::string> keywords = {"if",    "then", "else", "elif", "do",
                                                 "while", "until", "!",   "time", "{"};
  const auto values = variable_values(markdown);
  std::vector<ToolCommand> out;
  for (const auto& [first, text] : code_lines(markdown)) {
    const auto words = shell_words(text);
    bool start = true;
    ToolCommand* current = nullptr;
    for (const auto& w : words) {
      if (is_operator(w)) {
        start = true;
        current = nullptr;
        continue;
      }
      if (start) {
        if (keywords.count(w) || std::regex_match(w, kAssignment)) continue;
        start = false;
        if (w.rfind("flat_", 0) == 0) {
          out.push_back({w, "", label + ":" + std::to_string(first), {}});
          current = &out.back();
        }
        continue;
      }
      if (!current) continue;
      std::smatch m;
      if (std::regex_match(w, m, kVariable) && values.count(m[1])) {
        for (const auto& value : values.at(m[1]))
          for (const auto& v : shell_words(value))
            if (v.rfind("--", 0) == 0 && v.size() > 2) current->flags.push_back(v.substr(0, v.find('=')));
      } else if (w.rfind("--", 0) == 0 && w.size() > 2) {
        current->flags.push_back(w.substr(0, w.find('=')));
      } else if (current->flags.empty() && current->subcommand.empty() && !w.empty() && w[0] != '-' && w[0] != '$') {
        current->subcommand = w;
      }
    }
  }
  return out;
}

// Whether `help` names `flag` as a whole word (--depth is not --depth-format).
bool names_flag(const std::string& help, const std::string& flag) {
  for (size_t at = help.find(flag); at != std::string::npos; at = help.find(flag, at + 1)) {
    const size_t end = at + flag.size();
    const auto word_char = [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_'; };
    if ((at == 0 || !word_char(help[at - 1])) && (end == help.size() || !word_char(help[end]))) return true;
  }
  return false;
}

std::string help_text(const std::string& tool, const std::string& subcommand, const std::string& dir) {
  const std::string log = dir + "/" + tool + (subcommand.empty() ? "" : "_" + subcommand) + ".help";
  if (!fs::exists(log)) {
    std::vector<std::string> argv = {binary(tool)};
    if (!subcommand.empty()) argv.push_back(subcommand);
    argv.push_back("--help");
    run(argv, log);
  }
  return read_file(log);
}

std::set<std::string> json_names(const nlohmann::json& list) {
  std::set<std::string> out;
  for (const auto& item : list)
    out.insert(item.is_string() ? item.get<std::string>() : item.at("name").get<std::string>());
  return out;
}

}  // namespace

TEST_CASE("the own-videos guide names only flags its tools have", "[train][guide]") {
  const std::string d = fresh_dir("own_videos_flags").string();
  // The parser itself: a flag a tool lacks is found, on a continuation line, after an assignment.
  {
    const auto sample = tool_commands("```text\nX=1 flat_import re10k --in a \\\n  --no-such-flag=3 # --ignored\n"
                                      "for k in 1; do CUDA_VISIBLE_DEVICES=$k flat_eval --out x $E & done\n```\n"
                                      "```bash\n: \"${E:=--set a=1}\"\nE='--redo --x=\"\"'\n```\n",
                                      "sample");
    REQUIRE(sample.size() == 2);
    CHECK(sample[0].tool == "flat_import");
    CHECK(sample[0].subcommand == "re10k");
    CHECK(sample[0].flags == std::vector<std::string>{"--in", "--no-such-flag"});
    CHECK(sample[1].tool == "flat_eval");
    CHECK(sample[1].flags == std::vector<std::string>{"--out", "--set", "--redo", "--x"});
    CHECK_FALSE(names_flag(help_text("flat_import", "re10k", d), "--no-such-flag"));
    CHECK_FALSE(names_flag("--depth-format TEXT", "--depth"));
  }
  const std::string guide = read_file(kGuide);
  REQUIRE_FALSE(guide.empty());
  const auto commands = tool_commands(guide, "docs/own_videos.md");
  std::set<std::string> tools;
  size_t flags = 0;
  for (const auto& c : commands) {
    tools.insert(c.tool);
    REQUIRE(fs::exists(binary(c.tool)));
    const std::string help = help_text(c.tool, c.subcommand, d);
    REQUIRE_THAT(help, FLAT_CONTAINS("--help"));
    for (const auto& flag : c.flags) {
      INFO(c.where << ": " << c.tool << " " << c.subcommand << " " << flag);
      CHECK(names_flag(help, flag));
      ++flags;
    }
  }
  // Every step's tool is there (the parser found the commands at all).
  CHECK(tools == std::set<std::string>{"flat_synth", "flat_import", "flat_latents", "flat_train", "flat_eval",
                                       "flat_infer", "flat_mesh"});
  CHECK(flags > 60);
  std::printf("own_videos.md: %zu flat_ commands, %zu flags, each named by its tool's --help\n", commands.size(),
              flags);

  // The script the runner makes of the ```bash blocks is valid bash.
  const std::string bash = find_program("bash");
  REQUIRE_FALSE(bash.empty());
  REQUIRE(run_program({bash, kRunGuide}, d + "/script.sh", 60, {"GUIDE_PRINT=1"}) == 0);
  const std::string script = read_file(d + "/script.sh");
  CHECK_THAT(script, FLAT_CONTAINS("[run_guide] block 1 ") && FLAT_CONTAINS("flat_train --config"));
  CHECK_THAT(script, !FLAT_CONTAINS("yt-dlp"));  // ```text blocks are not run
  CHECK(run_program({bash, "-n", d + "/script.sh"}, d + "/syntax.log", 60) == 0);
}

TEST_CASE("the own-videos guide runs as written, rehearsed on tiny synthetic clips", "[train][guide]") {
  const std::string d = fresh_dir("own_videos_guide").string();
  const std::string bash = find_program("bash");
  REQUIRE_FALSE(bash.empty());
  // The rehearsal's values are the guide's own: the assignments of its line
  // `REHEARSAL=1 ... bash ../scripts/run_guide.sh`, with BIN and CONFIGS made
  // absolute (this build, this checkout).
  std::map<std::string, std::string> values;
  for (const auto& [number, text] : code_lines(read_file(kGuide)))
    if (text.find("REHEARSAL=1") != std::string::npos && text.find("run_guide.sh") != std::string::npos)
      for (const auto& w : shell_words(text)) {
        std::smatch m;
        if (std::regex_match(w, m, kAssignment)) values[m[1]] = m[2];
      }
  REQUIRE(values.count("REHEARSAL"));
  CHECK(values["CONFIGS"] == "../configs/tiny");
  CHECK(values["DEVICE"] == "cpu");
  CHECK(values["SCALE"] == "0.5");  // checked below, in each scene's depth_source
  CHECK(values["EVAL_SET"] == "80x144_f17");
  values["BIN"] = FLAT_BINARY_DIR;
  values["CONFIGS"] = std::string(FLAT_SOURCE_DIR) + "/configs/tiny";
  std::vector<std::string> env;
  for (const auto& [name, value] : values) env.push_back(name + "=" + value);
  const std::string log = d + "/guide.log";
  const int rc = run_program({bash, "-c", "cd '" + d + "' && exec bash '" + kRunGuide + "'"}, log, 1800, env);
  const std::string out = read_file(log);
  INFO(out.substr(out.size() > 6000 ? out.size() - 6000 : 0));
  REQUIRE(rc == 0);
  CHECK_THAT(out, FLAT_CONTAINS("[run_guide] every block of"));

  // Import: exactly the clips flat_synth made corrupt were reported, in the
  // summaries of the splits they landed in; every other clip is a scene in
  // exactly one split, with its depth and normals at metric scale.
  const std::map<std::string, std::vector<std::string>> made = {{"re10k", {"train", "test"}},
                                                                {"dl3dv", {"train", "test"}}};
  std::set<std::string> corrupt, clips;
  for (const auto& [ds, splits] : made)
    for (const auto& split : splits) {
      const auto manifest = nlohmann::json::parse(read_file(d + "/raw/" + ds + "/" + split + "/manifest.json"));
      const auto bad = json_names(manifest.at("corrupt"));
      corrupt.insert(bad.begin(), bad.end());
      for (const auto& clip : manifest.at("clips")) clips.insert(clip.at("name").get<std::string>());
    }
  CHECK(corrupt.size() == 2);
  std::set<std::string> reported;
  const std::vector<std::string> splits = {"train", "val", "test"};
  for (const std::string ds : {"re10k", "dl3dv"})
    for (const auto& split : splits) {
      const auto summary = nlohmann::json::parse(read_file(d + "/data/" + ds + "/" + split + "/import_summary.json"));
      INFO(summary.dump(1));
      CHECK(summary.at("imported").get<int>() + summary.at("already_present").get<int>() +
                summary.at("failed").get<int>() ==
            summary.at("clips").get<int>());
      const auto failed = json_names(summary.at("failures"));
      reported.insert(failed.begin(), failed.end());
    }
  CHECK(reported == corrupt);
  std::map<std::string, std::string> split_of;  // scene -> "<dataset>/<split>"
  for (const std::string ds : {"re10k", "dl3dv"})
    for (const auto& split : splits)
      for (const auto& dir : flat::data::scene_dirs_under(d + "/data/" + ds + "/" + split)) {
        const std::string name = fs::path(dir).filename().string();
        INFO(dir);
        CHECK(split_of.count(name) == 0);  // held-out scenes are in no other split
        split_of[name] = ds + "/" + split;
        const auto scene = flat::data::read_scene(dir);
        CHECK(scene.has_depth);
        CHECK(scene.has_normals);
        CHECK_THAT(scene.depth_source, FLAT_CONTAINS("metric scale 0.5"));
        CHECK_THAT(scene.normals_source, FLAT_CONTAINS("opengl -> opencv"));
        // Every stage's set in training and validation scenes; stage 4's in the test scenes.
        CHECK(flat::data::latent_set_list(scene) ==
              (split == "test" ? "80x144_f17" : "48x80_f9, 48x80_f17, 64x112_f17, 80x144_f17"));
      }
  for (const auto& clip : clips) {
    INFO(clip);
    CHECK(split_of.count(clip) == (corrupt.count(clip) ? 0u : 1u));
  }
  CHECK(split_of.size() == clips.size() - corrupt.size());  // 6 RealEstate10K clips and 5 DL3DV scenes
  std::map<std::string, int> per_split;
  for (const auto& [name, where] : split_of) ++per_split[where];
  CHECK(per_split["re10k/val"] == 1);
  CHECK(per_split["dl3dv/val"] == 1);
  CHECK(per_split["re10k/test"] == 2);
  CHECK(per_split["dl3dv/test"] == 2);

  // The four stages, each on its own latent set, each from the one before.
  const std::vector<std::string> sets = {"48x80_f9", "48x80_f17", "64x112_f17", "80x144_f17"};
  const int train_scenes = per_split["re10k/train"] + per_split["dl3dv/train"];
  for (int n = 1; n <= 4; ++n) {
    INFO("stage " << n);
    const std::string run_dir = d + "/runs/stage" + std::to_string(n);
    CHECK(fs::exists(run_dir + "/model.safetensors"));
    const auto report = nlohmann::json::parse(read_file(run_dir + "/data_report.json"));
    CHECK(report["train"]["latent_set"] == sets[size_t(n - 1)]);
    CHECK(report["train"]["scenes"] == train_scenes);
    CHECK(report["train"]["with_depth"].get<int>() > 0);
    CHECK(report["train"]["with_normals"].get<int>() > 0);
    CHECK(report["validation"]["scenes"] == 2);
    CHECK(report["train"]["datasets"].size() == 2);
    if (n > 1) {
      const std::string previous = "runs/stage" + std::to_string(n - 1);
      CHECK_THAT(out,
                 FLAT_CONTAINS("init: model weights of the earlier stage from " + previous + "/model.safetensors"));
      CHECK_THAT(read_file(run_dir + "/config.yaml"), FLAT_CONTAINS("path: " + previous));
    }
  }

  // flat_eval on the test clips, beside the three baselines.
  const auto results = flat::eval::read_results_json(d + "/runs/eval/stage4/results.json");
  const auto means = flat::eval::dataset_means(results.scores);
  REQUIRE(means.size() == 3);  // RE10K, DL3DV, all
  for (const auto& m : means) {
    INFO(m.dataset);
    CHECK(m.failed == 0);
    CHECK(std::isfinite(m.psnr));
    CHECK(std::isfinite(m.mean_colour_psnr));
    CHECK(std::isfinite(m.dataset_mean_psnr));
    CHECK(std::isfinite(m.swap_psnr));
  }
  CHECK(means.back().scenes == 4);
  std::printf("guide rehearsal: stage 4 on the test clips %.2f dB (mean-colour oracle %.2f, dataset mean %.2f, swap "
              "%.2f; random-encoder latents: not a result)\n",
              means.back().psnr, means.back().mean_colour_psnr, means.back().dataset_mean_psnr, means.back().swap_psnr);

  // flat_infer and flat_mesh on a held-out clip.
  std::string held_out;
  for (const auto& [name, where] : split_of)
    if (where == "re10k/test" && (held_out.empty() || name < held_out)) held_out = name;
  for (const std::string file : {"scene.ply", "scene.glb", "summary.json", "viewer/index.html"})
    CHECK(fs::exists(d + "/runs/infer/" + held_out + "/" + file));
  for (const std::string file : {"mesh.glb", "mesh.ply", "mesh.obj", "mesh_stats.json", "metrics.json"})
    CHECK(fs::exists(d + "/runs/mesh/" + held_out + "/" + file));
}
