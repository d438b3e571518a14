// Docs that match the code (issue #45): every command of README.md and
// docs/*.md (fenced code blocks and inline code spans) that runs one of our
// tools uses only flags that tool's --help lists, per subcommand where it has
// subcommands. Hidden aliases (old spellings a tool still accepts with a
// warning) are not listed, so a doc that uses one fails too: docs show the
// current names. docs/results/ holds dated records and is not checked.
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include "cli_fixtures.h"
#include "doc_commands.h"

namespace fs = std::filesystem;
using namespace flat::test;
using namespace flat::test::docs;

namespace {

// A tool's --help and, per subcommand, the subcommand's --help.
struct ToolHelp {
  HelpInfo top;
  std::map<std::string, HelpInfo> subs;
};

size_t edit_distance(const std::string& a, const std::string& b) {
  std::vector<size_t> prev(b.size() + 1), cur(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) prev[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    cur[0] = i;
    for (size_t j = 1; j <= b.size(); ++j)
      cur[j] = std::min({prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + (a[i - 1] == b[j - 1] ? 0 : 1)});
    std::swap(prev, cur);
  }
  return prev[b.size()];
}

// "did you mean" for a message: the closest listed flag, when close.
std::string nearest(const std::string& flag, const std::set<std::string>& known) {
  std::string best;
  size_t best_d = 4;
  for (const auto& k : known) {
    const size_t d = edit_distance(flag, k);
    if (d < best_d) best_d = d, best = k;
  }
  return best.empty() ? "" : " (closest listed: " + best + ")";
}

// Whether `written` (of --set written=value) is a config key: one of flat_train
// --help-config's full paths, a list written whole (data.datasets) or an
// element's key with its index (data.datasets[0].root).
bool config_key(const std::string& written, const std::set<std::string>& keys) {
  std::string key;  // written, with each [index] as []
  for (size_t i = 0; i < written.size(); ++i) {
    if (written[i] != '[') {
      key += written[i];
      continue;
    }
    const size_t close = written.find(']', i);
    if (close == std::string::npos) return false;
    key += "[]";
    i = close;
  }
  if (keys.count(key)) return true;
  for (const auto& k : keys)
    if (k.rfind(key + "[].", 0) == 0 || k.rfind(key + ".", 0) == 0) return true;
  return false;
}

// The --set keys of a command that are written out (no $VARIABLE, no "...").
std::vector<std::string> set_keys(const DocCommand& c) {
  std::vector<std::string> keys;
  for (size_t i = 0; i < c.args.size(); ++i) {
    std::string kv;
    if (c.args[i] == "--set" && i + 1 < c.args.size()) kv = c.args[i + 1];
    else if (c.args[i].rfind("--set=", 0) == 0) kv = c.args[i].substr(6);
    const size_t eq = kv.find('=');
    if (eq == std::string::npos || eq == 0) continue;
    const std::string key = kv.substr(0, eq);
    const bool literal = std::all_of(key.begin(), key.end(), [](unsigned char ch) {
      return std::islower(ch) || std::isdigit(ch) || ch == '_' || ch == '.' || ch == '[' || ch == ']';
    });
    if (literal && key.find("..") == std::string::npos) keys.push_back(key);
  }
  return keys;
}

// The problems of one command, each naming the file, line, flag and tool.
// config_keys: flat_train --help-config's keys, which --set takes in every tool.
std::vector<std::string> check_command(const std::string& file, const DocCommand& c,
                                       const std::map<std::string, ToolHelp>& helps,
                                       const std::set<std::string>& config_keys) {
  std::vector<std::string> problems;
  const ToolHelp& h = helps.at(c.tool);
  const std::string where = file + ":" + std::to_string(c.line) + ": `" + c.text + "`: ";
  for (const auto& key : set_keys(c))
    if (!config_key(key, config_keys))
      problems.push_back(where + "--set " + key + " is no config key (`flat_train --help-config` lists the full "
                         "key paths every tool's --set takes)");
  // Flags valid so far: the tool's own before a subcommand; after it, the
  // subcommand's (or, for a/b alternatives, any of theirs) and the parent's.
  std::vector<const HelpInfo*> scope = {&h.top};
  std::string scope_name = c.tool;
  bool sub_chosen = h.subs.empty();
  if (c.flags_only && !sub_chosen) {  // a line of flags under a command: any subcommand's
    scope.clear();
    for (const auto& s : h.subs) scope.push_back(&s.second);
    scope_name = c.tool + " <subcommand>";
    sub_chosen = true;
  }
  for (size_t i = 0; i < c.args.size(); ++i) {
    const std::string& a = c.args[i];
    const std::vector<std::string> flags = flags_of(a);
    if (!flags.empty()) {
      std::set<std::string> known = h.top.flags;
      for (const HelpInfo* s : scope) known.insert(s->flags.begin(), s->flags.end());
      for (const auto& f : flags)
        if (!known.count(f))
          problems.push_back(where + scope_name + " has no " + f + " (not in `" + scope_name + " --help`" +
                             nearest(f, known) + ")");
      // A value of the parent's option is not the subcommand's name.
      if (!sub_chosen && h.top.takes_value.count(flags[0]) && a.find('=') == std::string::npos) ++i;
      continue;
    }
    if (sub_chosen) continue;
    sub_chosen = true;
    // The subcommand: a name, or alternatives written a/b.
    std::vector<const HelpInfo*> chosen;
    std::istringstream parts(a);
    std::string part;
    bool all_known = true;
    while (std::getline(parts, part, '/')) {
      auto it = h.subs.find(part);
      if (it == h.subs.end()) all_known = false;
      else chosen.push_back(&it->second);
    }
    if (all_known && !chosen.empty()) {
      scope = chosen;
      scope_name = c.tool + " " + a;
      continue;
    }
    const bool a_name = !a.empty() && std::islower(static_cast<unsigned char>(a[0])) &&
                        std::all_of(a.begin(), a.end(), [](unsigned char ch) {
      return std::islower(ch) || std::isdigit(ch) || ch == '_';
    });
    if (a_name) problems.push_back(where + c.tool + " has no subcommand " + a);
    // A placeholder (<sub>, ...): the flags of any subcommand pass.
    scope.clear();
    for (const auto& s : h.subs) scope.push_back(&s.second);
    scope_name = c.tool + " <subcommand>";
  }
  return problems;
}

// The tools: apps/ and data_tools/, NAME.cpp or NAME/ (CMake's rule).
std::set<std::string> tool_names() {
  std::set<std::string> names;
  for (const char* dir : {"apps", "data_tools"})
    for (const auto& e : fs::directory_iterator(fs::path(FLAT_SOURCE_DIR) / dir)) {
      if (e.is_directory()) names.insert(e.path().filename().string());
      else if (e.path().extension() == ".cpp") names.insert(e.path().stem().string());
    }
  return names;
}

std::map<std::string, ToolHelp> read_helps(const std::set<std::string>& tools, const std::string& log_dir) {
  std::map<std::string, ToolHelp> helps;
  for (const auto& t : tools) {
    INFO(t);
    const ToolResult top = tool(t, {"--help"}, log_dir, t + "_help");
    REQUIRE(top.rc == 0);
    ToolHelp& h = helps[t];
    h.top = parse_help(top.output);
    REQUIRE(h.top.flags.count("--help"));  // the layout is the one parse_help reads
    for (const auto& s : h.top.subcommands) {
      const ToolResult sub = tool(t, {s, "--help"}, log_dir, t + "_" + s + "_help");
      REQUIRE(sub.rc == 0);
      h.subs[s] = parse_help(sub.output);
    }
  }
  return helps;
}

// The keys of `flat_train --help-config`: the first column of its table.
std::set<std::string> parse_config_keys(const std::string& help_config) {
  std::set<std::string> keys;
  std::istringstream in(help_config);
  std::string l;
  while (std::getline(in, l))
    if (l.rfind("| `", 0) == 0) keys.insert(l.substr(3, l.find('`', 3) - 3));
  return keys;
}

// A tool with one subcommand, as CLI11 prints it.
const char* kFakeTop = R"(fake: a tool
Usage: ./fake [OPTIONS] SUBCOMMAND

Options:
  -h,--help                   Print this help message and exit
  --log-level TEXT:{trace,debug}=info
                              trace | debug
  --version                   Display program version information and exit

Subcommands:
  run                         does things
)";
const char* kFakeRun = R"(does things
Usage: ./fake run [OPTIONS]

Options:
  -h,--help                   Print this help message and exit
  --scenes,--folders TEXT ... REQUIRED
                              scene folders
  --depth-metric Needs: --depth
                              a flag
  --count INT:POSITIVE=1      how many
  --set TEXT ...              override a config key
)";

}  // namespace

TEST_CASE("docs commands: extraction from fences, continuations, comments, pipes and inline spans", "[docs]") {
  const std::set<std::string> tools = {"flat_train", "flat_bench", "flat_eval"};
  const std::string md =
      "Intro `flat_train --config a.yaml\n--set x=1` and `flat_bench raster\\|decoder` in a table.\n"
      "\n"
      "```bash\n"
      "build/flat_train --config a.yaml \\\n"
      "  --resume r   # a comment --not-a-flag\n"
      "$B/flat_bench raster --repeats 2 | tee log.txt\n"
      "CUDA_VISIBLE_DEVICES=0 torchrun --nproc-per-node 8 --no-python flat_train --nproc 2\n"
      "srun bash -c 'X=1 flat_eval --model m'\n"
      "flat_test_train \"[cli]\"   # not a tool\n"
      "  --precision fp32|bf16  --repeats 3   # flags of the last tool above\n"
      "```\n"
      "\n"
      "```json\n"
      "{\"cmd\": \"flat_train --json\"}\n"
      "```\n";
  const auto cmds = extract_commands(md, tools);
  REQUIRE(cmds.size() == 7);
  CHECK(cmds[0].tool == "flat_train");
  CHECK(cmds[0].line == 1);
  CHECK(cmds[0].args == std::vector<std::string>{"--config", "a.yaml", "--set", "x=1"});  // across the line break
  CHECK(cmds[1].tool == "flat_bench");
  CHECK(cmds[1].args == std::vector<std::string>{"raster"});  // \| in a table is a |: the next command
  CHECK(cmds[2].line == 5);
  CHECK(cmds[2].args == std::vector<std::string>{"--config", "a.yaml", "--resume", "r"});  // continued; comment gone
  CHECK(cmds[3].args == std::vector<std::string>{"raster", "--repeats", "2"});             // up to the pipe
  CHECK(cmds[4].args == std::vector<std::string>{"--nproc", "2"});                         // after the launcher
  CHECK(cmds[5].tool == "flat_eval");                                                     // inside bash -c '...'
  CHECK(cmds[5].line == 9);
  CHECK(cmds[6].tool == "flat_eval");  // the block's last tool
  CHECK(cmds[6].flags_only);
  CHECK(cmds[6].args == std::vector<std::string>{"--precision", "fp32", "bf16", "--repeats", "3"});
  CHECK(!cmds[0].flags_only);

  CHECK(flag_of("--size=16x24") == "--size");
  CHECK(flag_of("[--remove-files]") == "--remove-files");
  CHECK(flag_of("--").empty());
  CHECK(flag_of("-1").empty());
  CHECK(flag_of("x=--y").empty());
}

TEST_CASE("docs commands: the check names the file, line and flag of a flag --help does not list", "[docs]") {
  std::map<std::string, ToolHelp> helps;
  helps["fake"].top = parse_help(kFakeTop);
  helps["fake"].subs["run"] = parse_help(kFakeRun);
  const HelpInfo& run = helps["fake"].subs["run"];
  CHECK(helps["fake"].top.subcommands == std::vector<std::string>{"run"});
  CHECK(run.flags ==
        std::set<std::string>{"-h", "--help", "--scenes", "--folders", "--depth-metric", "--count", "--set"});
  CHECK(run.takes_value.count("--scenes"));
  CHECK(!run.takes_value.count("--depth-metric"));  // "Needs:" is not a type
  CHECK(helps["fake"].top.takes_value.count("--log-level"));

  const std::set<std::string> keys =
      parse_config_keys("| key | default | meaning |\n|---|---|---|\n| `steps` | `20000` | steps |\n"
                        "| `data.datasets[].root` | `\"\"` | folder |\n| `pipeline.prune_opacity` | `0.05` | x |\n");
  CHECK(keys == std::set<std::string>{"steps", "data.datasets[].root", "pipeline.prune_opacity"});
  auto problems_of = [&](const std::string& line) {
    const auto cmds = extract_commands("```\n" + line + "\n```\n", {"fake"});
    REQUIRE(cmds.size() == 1);
    return check_command("docs/x.md", cmds[0], helps, keys);
  };
  CHECK(problems_of("fake run --scenes a b --count=3 --depth-metric").empty());
  CHECK(problems_of("fake --log-level debug run --count 2").empty());  // debug is the value, run the subcommand
  CHECK(problems_of("fake run --log-level warn").empty());             // the parent's options pass after it
  const auto stale = problems_of("fake run --scene a");
  REQUIRE(stale.size() == 1);
  CHECK_THAT(stale[0], FLAT_CONTAINS("docs/x.md:2:"));
  CHECK_THAT(stale[0], FLAT_CONTAINS("fake run has no --scene"));
  CHECK_THAT(stale[0], FLAT_CONTAINS("closest listed: --scenes"));
  CHECK(problems_of("fake --count 2 run").size() == 1);  // a subcommand's flag before the subcommand
  CHECK_THAT(problems_of("fake walk --count 2")[0], FLAT_CONTAINS("fake has no subcommand walk"));
  CHECK(problems_of("fake run --scenes/--folders a").empty());  // alternatives, each listed
  {
    // A line of flags under a command: any subcommand's flags pass, others fail.
    const auto cmds = extract_commands("```\nfake run --count 1\n  --scenes a --count 2\n  --dtype bf16\n```\n", {"fake"});
    REQUIRE(cmds.size() == 3);
    CHECK(check_command("docs/x.md", cmds[1], helps, keys).empty());
    const auto stale_line = check_command("docs/x.md", cmds[2], helps, keys);
    REQUIRE(stale_line.size() == 1);
    CHECK_THAT(stale_line[0], FLAT_CONTAINS("docs/x.md:4:"));
    CHECK_THAT(stale_line[0], FLAT_CONTAINS("has no --dtype"));
  }
  CHECK(problems_of("fake run --scenes/--scene a").size() == 1);
  // --set takes full key paths (a list whole, or an element by index); $KEY is not checked.
  CHECK(problems_of("fake run --set steps=4 --set=data.datasets[0].root=x --set data.datasets=[]").empty());
  CHECK(problems_of("fake run --set $KEY=1 --set a.b...=2").empty());
  const auto relative = problems_of("fake run --set prune_opacity=0.4");
  REQUIRE(relative.size() == 1);
  CHECK_THAT(relative[0], FLAT_CONTAINS("--set prune_opacity is no config key"));
}

TEST_CASE("docs commands: every command in README.md and docs/*.md uses flags its tool's --help lists", "[docs]") {
  const std::string log_dir = fresh_dir("docs_commands").string();
  const std::set<std::string> tools = tool_names();
  REQUIRE(tools.count("flat_train"));
  const auto helps = read_helps(tools, log_dir);
  const ToolResult help_config = tool("flat_train", {"--help-config"}, log_dir, "help_config");
  REQUIRE(help_config.rc == 0);
  const std::set<std::string> config_keys = parse_config_keys(help_config.output);
  REQUIRE(config_keys.count("pipeline.prune_opacity"));

  std::vector<fs::path> files = {fs::path(FLAT_SOURCE_DIR) / "README.md"};
  for (const auto& e : fs::directory_iterator(fs::path(FLAT_SOURCE_DIR) / "docs"))
    if (e.is_regular_file() && e.path().extension() == ".md") files.push_back(e.path());
  std::sort(files.begin() + 1, files.end());

  size_t checked = 0;
  std::set<std::string> seen_tools;
  std::vector<std::string> problems;
  for (const auto& path : files) {
    const std::string rel = fs::relative(path, FLAT_SOURCE_DIR).string();
    for (const auto& c : extract_commands(read_file(path), tools)) {
      ++checked;
      seen_tools.insert(c.tool);
      for (auto& p : check_command(rel, c, helps, config_keys)) problems.push_back(std::move(p));
    }
  }
  // The extraction found the docs' commands at all: many, of every tool.
  INFO(checked << " commands checked");
  CHECK(checked > 100);
  for (const auto& t : tools) {
    INFO("no command of " << t << " found in the docs");
    CHECK(seen_tools.count(t));
  }
  for (const auto& p : problems) FAIL_CHECK(p);
  CHECK(problems.empty());
}
