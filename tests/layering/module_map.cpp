#include "layering/module_map.h"

#include <algorithm>
#include <fstream>
#include <regex>
#include <set>
#include <sstream>
#include <stdexcept>

#include "layering/source_files.h"

namespace fs = std::filesystem;

namespace flat::layering {
namespace {

std::vector<std::string> read_lines(const fs::path& path) {
  std::istringstream in(read_text(path));
  std::vector<std::string> lines;
  for (std::string l; std::getline(in, l);) lines.push_back(l);
  return lines;
}

// CMake text without its comments (no '#' appears inside a string in the
// calls we read).
std::string strip_cmake_comments(const std::string& text) {
  std::istringstream in(text);
  std::string out;
  for (std::string l; std::getline(in, l);) out += l.substr(0, l.find('#')) + "\n";
  return out;
}

std::vector<std::string> split_ws(const std::string& s) {
  std::istringstream in(s);
  std::vector<std::string> out;
  for (std::string w; in >> w;) out.push_back(w);
  return out;
}

std::string join(const std::vector<std::string>& v, const std::string& sep) {
  std::string out;
  for (size_t i = 0; i < v.size(); ++i) out += (i ? sep : "") + v[i];
  return out;
}

std::string deps_text(const ModuleMap& map, const std::string& m) {
  const auto& d = map.deps.at(m);
  return d.empty() ? "(none)" : join(d, ", ");
}

std::string rel(const fs::path& p, const fs::path& root) { return p.lexically_relative(root).generic_string(); }

// One #include "..." or <flat/...> of a file that names a module: as
// "flat/<module>/..." (public) or "<module>/..." (private, under src/).
struct ModuleInclude {
  int line;
  std::string text;    // what is included, as written
  std::string module;  // the module it belongs to
  bool is_private;
};

std::vector<ModuleInclude> module_includes(const fs::path& file, const ModuleMap& map) {
  static const std::regex include_re(R"(^\s*#\s*include\s*(["<])([^">]+)[">])");
  std::vector<ModuleInclude> out;
  const auto lines = read_lines(file);
  for (size_t i = 0; i < lines.size(); ++i) {
    if (lines[i].find("include") == std::string::npos) continue;
    std::smatch m;
    if (!std::regex_search(lines[i], m, include_re)) continue;
    const std::string inc = m[2].str();
    const auto slash = inc.find('/');
    if (slash == std::string::npos) continue;  // a file next to this one
    const std::string first = inc.substr(0, slash);
    if (first == "flat") {
      const auto slash2 = inc.find('/', slash + 1);
      if (slash2 == std::string::npos) continue;
      const std::string mod = inc.substr(slash + 1, slash2 - slash - 1);
      if (map.deps.count(mod)) out.push_back({int(i + 1), inc, mod, false});
    } else if (m[1].str() == "\"" && map.deps.count(first) && !fs::exists(file.parent_path() / inc)) {
      // "render/x.h" from src/ (a private include root of every module);
      // a path relative to the including file is that module's own.
      out.push_back({int(i + 1), inc, first, true});
    }
  }
  return out;
}

void check_module(const fs::path& root, const ModuleMap& map, const std::string& mod, std::vector<Violation>& out) {
  const auto& deps = map.deps.at(mod);
  std::set<std::string> used;
  for (const auto& dir : {root / "src" / mod, root / "include" / "flat" / mod}) {
    const bool public_dir = dir.parent_path().filename() == "flat";
    for (const auto& file : code_files(dir)) {
      for (const auto& inc : module_includes(file, map)) {
        const std::string where = "module " + mod + " (DEPS: " + deps_text(map, mod) + ")";
        if (public_dir && inc.is_private) {
          out.push_back({rel(file, root), inc.line,
                         "public header of module " + mod + " includes \"" + inc.text +
                             "\", a private header under src/ (not on an installed library's include path); "
                             "move it to include/flat/" + inc.module + "/"});
          continue;
        }
        if (inc.module == mod) continue;
        used.insert(inc.module);
        if (inc.is_private) {
          out.push_back({rel(file, root), inc.line,
                         where + " includes \"" + inc.text + "\", a private header of module " + inc.module +
                             " (src/" + inc.module + "/); share it from include/flat/" + inc.module + "/"});
        } else if (std::find(deps.begin(), deps.end(), inc.module) == deps.end()) {
          out.push_back({rel(file, root), inc.line,
                         where + " includes \"" + inc.text + "\" of module " + inc.module +
                             ", which is not in its DEPS; add flat_mod_" + inc.module +
                             " to flat_add_module(" + mod + " DEPS ...) in CMakeLists.txt"});
        }
      }
    }
  }
  for (const auto& d : deps)
    if (!used.count(d))
      out.push_back({"CMakeLists.txt", 0,
                     "module " + mod + " (DEPS: " + deps_text(map, mod) + ") names flat_mod_" + d +
                         " in its DEPS but no file of src/" + mod + "/ or include/flat/" + mod +
                         "/ includes a header of module " + d + "; remove it"});
}

// The modules an executable links: its FLAT_MODULES and their DEPS, closed.
std::set<std::string> link_closure(const ModuleMap& map, const std::vector<std::string>& roots) {
  std::set<std::string> seen;
  std::vector<std::string> todo(roots.begin(), roots.end());
  while (!todo.empty()) {
    const std::string m = todo.back();
    todo.pop_back();
    if (!map.deps.count(m) || !seen.insert(m).second) continue;
    for (const auto& d : map.deps.at(m)) todo.push_back(d);
  }
  return seen;
}

void check_tool(const fs::path& root, const ModuleMap& map, const std::string& tool, const std::vector<fs::path>& files,
                std::vector<Violation>& out) {
  const auto it = map.tool_modules.find(tool);
  if (it == map.tool_modules.end()) {
    out.push_back({rel(files.front(), root), 0,
                   "executable " + tool + " has no set(FLAT_MODULES_" + tool + " ...) in CMakeLists.txt"});
    return;
  }
  const auto closure = link_closure(map, it->second);
  for (const auto& file : files)
    for (const auto& inc : module_includes(file, map)) {
      if (inc.is_private)
        out.push_back({rel(file, root), inc.line,
                       "executable " + tool + " includes \"" + inc.text + "\", a private header of module " +
                           inc.module + " (src/" + inc.module + "/)"});
      else if (!closure.count(inc.module))
        out.push_back({rel(file, root), inc.line,
                       "executable " + tool + " (FLAT_MODULES_" + tool + ": " + join(it->second, ", ") +
                           ") includes \"" + inc.text + "\" of module " + inc.module +
                           ", which it does not link; add it to FLAT_MODULES_" + tool + " in CMakeLists.txt"});
    }
}

// "loss, optim, distributed" or "core, render (the baselines' rasterizers)":
// names split at commas, parenthesised notes and backquotes dropped.
std::vector<std::string> table_names(std::string cell) {
  std::string plain;
  int depth = 0;
  for (char c : cell) {
    if (c == '(') ++depth;
    else if (c == ')') depth = std::max(0, depth - 1);
    else if (depth == 0 && c != '`') plain += c;
  }
  std::vector<std::string> out;
  std::istringstream in(plain);
  for (std::string name; std::getline(in, name, ',');) {
    const auto w = split_ws(name);
    if (w.size() == 1 && w[0] != "none") out.push_back(w[0]);
  }
  return out;
}

}  // namespace

std::string to_string(const Violation& v) {
  return v.file + (v.line > 0 ? ":" + std::to_string(v.line) : "") + ": " + v.message;
}

ModuleMap read_module_map(const fs::path& root) {
  const fs::path path = root / "CMakeLists.txt";
  const std::string text = strip_cmake_comments(read_text(path));
  ModuleMap map;
  static const std::regex module_re(R"(flat_add_module\s*\(([^)]*)\))");
  for (auto it = std::sregex_iterator(text.begin(), text.end(), module_re); it != std::sregex_iterator(); ++it) {
    const auto words = split_ws((*it)[1].str());
    if (words.empty() || (words.size() > 1 && words[1] != "DEPS"))
      throw std::runtime_error(path.string() + ": cannot read flat_add_module(" + (*it)[1].str() + ")");
    const std::string& name = words[0];
    if (map.deps.count(name)) throw std::runtime_error(path.string() + ": module " + name + " declared twice");
    auto& deps = map.deps[name];
    for (size_t i = 2; i < words.size(); ++i)
      if (words[i].rfind("flat_mod_", 0) == 0) deps.push_back(words[i].substr(9));  // others: not modules
    map.order.push_back(name);
  }
  if (map.order.empty()) throw std::runtime_error(path.string() + ": no flat_add_module(...) found");
  static const std::regex tool_re(R"(set\s*\(\s*FLAT_MODULES_(\w+)([^)]*)\))");
  for (auto it = std::sregex_iterator(text.begin(), text.end(), tool_re); it != std::sregex_iterator(); ++it)
    map.tool_modules[(*it)[1].str()] = split_ws((*it)[2].str());
  return map;
}

std::vector<Violation> check_includes(const fs::path& root, const ModuleMap& map) {
  std::vector<Violation> out;
  for (const auto& dir : {root / "src", root / "include" / "flat"}) {
    if (!fs::is_directory(dir)) continue;
    std::vector<fs::path> subdirs;
    for (const auto& e : fs::directory_iterator(dir))
      if (e.is_directory()) subdirs.push_back(e.path());
    std::sort(subdirs.begin(), subdirs.end());
    for (const auto& sub : subdirs)
      if (!map.deps.count(sub.filename().string()))
        out.push_back({rel(sub, root), 0,
                       "folder of no module: no flat_add_module(" + sub.filename().string() +
                           " ...) in CMakeLists.txt, so its includes go unchecked"});
  }
  for (const auto& mod : map.order) check_module(root, map, mod, out);
  // dir/NAME.cpp -> NAME; dir/NAME/*.cpp -> NAME (cmake/FlatModules.cmake).
  for (const char* dir : {"apps", "data_tools"}) {
    if (!fs::is_directory(root / dir)) continue;
    std::vector<fs::path> entries;
    for (const auto& e : fs::directory_iterator(root / dir)) entries.push_back(e.path());
    std::sort(entries.begin(), entries.end());
    for (const auto& e : entries) {
      if (fs::is_directory(e)) {
        const auto files = code_files(e);
        if (!files.empty()) check_tool(root, map, e.filename().string(), files, out);
      } else if (e.extension() == ".cpp") {
        check_tool(root, map, e.stem().string(), {e}, out);
      }
    }
  }
  return out;
}

std::vector<Violation> check_doc_table(const fs::path& root, const ModuleMap& map) {
  const fs::path path = root / "docs" / "development.md";
  const auto lines = read_lines(path);
  const std::string doc = rel(path, root);
  std::vector<Violation> out;
  size_t i = 0;
  while (i < lines.size() && lines[i].rfind("| module | DEPS", 0) != 0) ++i;
  if (i == lines.size()) return {{doc, 0, "no table starting with \"| module | DEPS\""}};
  std::map<std::string, int> seen;  // module -> its row's line
  for (i += 2; i < lines.size() && lines[i].rfind("|", 0) == 0; ++i) {
    std::vector<std::string> cells;
    std::istringstream in(lines[i].substr(1));
    for (std::string c; std::getline(in, c, '|');) cells.push_back(c);
    const int line = int(i + 1);
    if (cells.size() < 2) {
      out.push_back({doc, line, "a row of the module table without two cells"});
      continue;
    }
    auto listed = table_names(cells[1]);
    std::sort(listed.begin(), listed.end());
    for (const auto& mod : table_names(cells[0])) {
      if (!map.deps.count(mod)) {
        out.push_back({doc, line, "module table lists " + mod + ", which CMakeLists.txt does not declare"});
        continue;
      }
      if (seen.count(mod)) out.push_back({doc, line, "module table lists " + mod + " twice"});
      seen[mod] = line;
      auto declared = map.deps.at(mod);
      std::sort(declared.begin(), declared.end());
      if (listed != declared)
        out.push_back({doc, line,
                       "module table says " + mod + " depends on " + (listed.empty() ? "none" : join(listed, ", ")) +
                           "; CMakeLists.txt's DEPS: " + deps_text(map, mod)});
    }
  }
  for (const auto& mod : map.order)
    if (!seen.count(mod)) out.push_back({doc, 0, "module table leaves out module " + mod + " (DEPS: " + deps_text(map, mod) + ")"});
  return out;
}

std::string doc_table(const ModuleMap& map) {
  std::string out = "| module | DEPS (the modules whose headers it includes) |\n|---|---|\n";
  for (const auto& m : map.order) {
    const auto& d = map.deps.at(m);
    out += "| " + m + " | " + (d.empty() ? "none" : join(d, ", ")) + " |\n";
  }
  return out;
}

}  // namespace flat::layering
