// One command-line vocabulary (issue #45): a flag name means one thing in
// every tool. The canonical table is docs/cli_vocabulary.txt (its header says
// what each column means); these tests read every tool's --help, and each
// subcommand's, and hold them to it. Old spellings stay readable as hidden
// names that warn; --set takes the same full key paths in every tool.
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include "cli_fixtures.h"
#include "model_fixtures.h"

namespace fs = std::filesystem;
using namespace flat::test;

namespace {

const std::vector<std::string> kVocabularyTools = {"flat_import", "flat_synth",  "flat_vae",   "flat_latents",
                                                   "flat_pack",   "flat_render", "flat_train", "flat_infer",
                                                   "flat_eval",   "flat_mesh",   "flat_bench"};

std::string lower(std::string s) {
  for (auto& c : s) c = char(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

std::string trim(const std::string& s) {
  const auto a = s.find_first_not_of(" \t"), b = s.find_last_not_of(" \t");
  return a == std::string::npos ? "" : s.substr(a, b - a + 1);
}

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  for (std::string item; std::getline(ss, item, sep);) out.push_back(trim(item));
  return out;
}

struct Flag {
  std::vector<std::string> keywords;  // lower case
  std::set<std::string> tools;        // that must have it
};
struct OldName {
  std::string page, old_name, new_name, value;
};
struct Vocabulary {
  std::map<std::string, Flag> flags;
  std::vector<OldName> old_names;
};

Vocabulary read_vocabulary() {
  const std::string path = std::string(FLAT_SOURCE_DIR) + "/docs/cli_vocabulary.txt";
  std::ifstream in(path);
  REQUIRE(in.good());
  Vocabulary v;
  for (std::string line; std::getline(in, line);) {
    if (trim(line).empty() || trim(line)[0] == '#') continue;
    const auto cols = split(line, '|');
    INFO(path << ": " << line);
    if (cols[0] == "old") {
      REQUIRE(cols.size() == 5);
      v.old_names.push_back({cols[1], cols[2], cols[3], cols[4]});
      continue;
    }
    REQUIRE(cols.size() == 4);
    Flag f;
    for (const auto& k : split(cols[1], ',')) f.keywords.push_back(lower(k));
    if (cols[2] == "all") {
      f.tools.insert(kVocabularyTools.begin(), kVocabularyTools.end());
    } else if (cols[2] != "-") {
      std::stringstream ss(cols[2]);
      for (std::string t; ss >> t;) f.tools.insert(t);
    }
    v.flags[cols[0]] = f;
  }
  return v;
}

// One --help page: its flags, each with the text of its entry (type, choices,
// default and description, which CLI11 puts on the same or the next lines),
// and the subcommands it lists.
struct HelpPage {
  std::map<std::string, std::string> flags;
  std::vector<std::string> subcommands;
};

HelpPage parse_help(const std::string& text) {
  HelpPage page;
  std::stringstream ss(text);
  std::string section, current;
  for (std::string line; std::getline(ss, line);) {
    if (!line.empty() && line[0] != ' ') {
      section = line;
      current.clear();
      continue;
    }
    if (section.rfind("Subcommands", 0) == 0 && line.size() > 2 && line[2] != ' ') {
      std::stringstream ls(line);
      std::string name;
      ls >> name;
      page.subcommands.push_back(name);
      continue;
    }
    if (line.rfind("  -", 0) == 0) {
      std::stringstream ls(line);
      std::string names;
      ls >> names;
      const std::string rest = line.substr(line.find(names) + names.size());
      current.clear();
      for (const auto& n : split(names, ','))
        if (n.rfind("--", 0) == 0) {
          page.flags[n] += rest;
          if (current.empty()) current = n;
        }
      continue;
    }
    if (!current.empty() && !trim(line).empty()) page.flags[current] += " " + trim(line);  // a continued entry
  }
  return page;
}

// Every help page: each tool's, and each of its subcommands'.
std::map<std::string, HelpPage> help_pages(const std::string& dir) {
  std::map<std::string, HelpPage> pages;
  for (const auto& t : kVocabularyTools) {
    auto r = tool(t, {"--help"}, dir, t);
    INFO(r.output);
    REQUIRE(r.rc == 0);
    pages[t] = parse_help(r.output);
    for (const auto& sub : pages[t].subcommands) {
      auto s = tool(t, {sub, "--help"}, dir, t + "_" + sub);
      INFO(s.output);
      REQUIRE(s.rc == 0);
      pages[t + " " + sub] = parse_help(s.output);
    }
  }
  return pages;
}

std::string tool_of(const std::string& page) { return page.substr(0, page.find(' ')); }

}  // namespace

TEST_CASE("vocabulary: one flag name, one meaning, in every tool's --help (docs/cli_vocabulary.txt)",
          "[cli][vocabulary]") {
  const Vocabulary v = read_vocabulary();
  const std::string dir = fresh_dir("vocabulary_help").string();
  const auto pages = help_pages(dir);
  REQUIRE(pages.count("flat_bench raster"));  // subcommands were found
  REQUIRE(pages.count("flat_vae encode"));

  std::map<std::string, std::vector<std::string>> pages_of;  // flag -> pages naming it
  for (const auto& [page, help] : pages)
    for (const auto& [flag, text] : help.flags) pages_of[flag].push_back(page);

  // A name on two pages is a shared word: its meaning must be written down.
  for (const auto& [flag, where] : pages_of) {
    if (where.size() < 2 || v.flags.count(flag)) continue;
    std::string list;
    for (const auto& p : where) list += " [" + p + "]";
    FAIL_CHECK(flag << " is on" << list << " but not in docs/cli_vocabulary.txt: give it its one meaning there");
  }
  // Wherever a listed flag appears, its entry says that meaning.
  for (const auto& [page, help] : pages)
    for (const auto& [flag, text] : help.flags) {
      auto it = v.flags.find(flag);
      if (it == v.flags.end()) continue;
      bool said = false;
      for (const auto& k : it->second.keywords) said = said || lower(text).find(k) != std::string::npos;
      if (!said)
        FAIL_CHECK("[" << page << "] " << flag << " does not mean what docs/cli_vocabulary.txt says (none of its "
                       << "keywords in '" << trim(text) << "')");
    }
  // The shared flags exist in every tool they are listed for.
  for (const auto& [flag, f] : v.flags)
    for (const auto& t : f.tools) {
      bool has = false;
      for (const auto& [page, help] : pages) has = has || (tool_of(page) == t && help.flags.count(flag));
      if (!has) FAIL_CHECK(t << " lacks " << flag << " (docs/cli_vocabulary.txt lists it for " << t << ")");
    }
  // Old names are hidden: never on their own pages, nor anywhere when no flag has the name now.
  std::set<std::string> reported;
  for (const auto& o : v.old_names) {
    const bool retired = v.flags.count(o.old_name) == 0;
    for (const auto& [page, help] : pages)
      if ((page == o.page || retired) && help.flags.count(o.old_name) && reported.insert(page + o.old_name).second)
        FAIL_CHECK("[" << page << "] shows the old name " << o.old_name << " (use " << o.new_name << ")");
  }
}

TEST_CASE("vocabulary: old names still work, hidden, and say what to use instead", "[cli][vocabulary]") {
  const Vocabulary v = read_vocabulary();
  REQUIRE(!v.old_names.empty());
  const std::string dir = fresh_dir("vocabulary_old").string();
  int n = 0;
  for (const auto& o : v.old_names) {
    INFO(o.page << " " << o.old_name << " " << o.value);
    std::vector<std::string> args = split(o.page, ' ');
    const std::string t = args.front();
    args.erase(args.begin());
    // With --help the tool stops after parsing: the old name was read (CLI11 refuses an unknown one, exit 2).
    args.insert(args.end(), {o.old_name, o.value, "--help"});
    auto r = tool(t, args, dir, "old_" + std::to_string(n++));
    CHECK(r.rc == 0);
    CHECK_THAT(r.output, FLAT_CONTAINS(o.old_name + " is an old name; use " + o.new_name));
    // Also in the --name=value form.
    args = split(o.page, ' ');
    args.erase(args.begin());
    args.insert(args.end(), {o.old_name + "=" + o.value, "--help"});
    auto eq = tool(t, args, dir, "old_" + std::to_string(n++));
    CHECK(eq.rc == 0);
    CHECK_THAT(eq.output, FLAT_CONTAINS("use " + o.new_name));
  }
  // Read as the new name, not only accepted: flat_synth --scenes 2 makes two scenes.
  auto two = tool("flat_synth", {"--out", dir + "/synth", "--scenes", "2", "--frames", "2", "--size", "8x8"}, dir,
                  "synth_scenes");
  REQUIRE(two.rc == 0);
  CHECK(fs::is_directory(dir + "/synth/room_000001"));
  CHECK_THAT(two.output, FLAT_CONTAINS("use --count"));
}

TEST_CASE("vocabulary: --set takes flat_train's full key paths in every tool", "[cli][vocabulary]") {
  const std::string dir = fresh_dir("vocabulary_set").string();
  // flat_train: the key as the config file spells it.
  auto train = tool("flat_train", {"--config", std::string(FLAT_SOURCE_DIR) + "/configs/tiny/stage1.yaml", "--set",
                                   "pipeline.prune_opacity=0.375", "--print-config"},
                    dir, "train");
  REQUIRE(train.rc == 0);
  CHECK_THAT(train.output, FLAT_CONTAINS("prune_opacity: 0.375"));

  // flat_infer and flat_eval: the same key pasted from a training command.
  const std::string model = dir + "/model.safetensors", scene = dir + "/scenes/room";
  write_tiny_model(model);
  write_scene_with_latents(scene, 3);
  const std::vector<std::string> infer = {"--model", model, "--scene", scene, "--no-glb", "--no-renders",
                                          "--no-video", "--novel", "none", "--device", "cpu"};
  const std::vector<std::string> eval = {"--model", model, "--scenes", "S=" + dir + "/scenes", "--device", "cpu"};
  for (const auto& [t, base] : {std::pair{std::string("flat_infer"), infer}, std::pair{std::string("flat_eval"), eval}}) {
    INFO(t);
    auto with = [&, base = base](const std::string& set, const std::string& out) {
      auto args = base;
      args.insert(args.end(), {"--out", dir + "/" + out, "--set", set});
      return tool(t, args, dir, out);
    };
    auto full = with("pipeline.prune_opacity=0.375", t + "_full");
    INFO(full.output);
    CHECK(full.rc == 0);
    CHECK_THAT(full.output, !FLAT_CONTAINS("use --set"));
    // The old pipeline-relative spelling still works, and says what to write.
    auto relative = with("prune_opacity=0.375", t + "_relative");
    INFO(relative.output);
    CHECK(relative.rc == 0);
    CHECK_THAT(relative.output, FLAT_CONTAINS("use --set pipeline.prune_opacity=0.375"));
    // A key of another section is named, not read as a pipeline key.
    auto other = with("data.height=50", t + "_other");
    CHECK(other.rc != 0);
    CHECK_THAT(other.output, FLAT_CONTAINS("data.height"));
  }
}
