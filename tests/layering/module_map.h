// The module map as written in the top CMakeLists.txt (flat_add_module(<m>
// DEPS ...), set(FLAT_MODULES_<tool> ...)) held against what the sources
// actually include, and against the table of docs/development.md. Plain C++
// (no torch): it reads text files only.
//
// The rules (docs/development.md, "Modules and dependencies"):
// - a module's files (src/<m>/ and include/flat/<m>/, headers too) include
//   another module's headers only if that module is in its own DEPS: direct
//   DEPS, not what they bring transitively, so that DEPS is the map;
// - only public headers: "flat/<other>/..." from include/; "<other>/..." (a
//   private header under src/<other>/) is never allowed across modules;
// - a public header (include/flat/<m>/) includes no private header at all:
//   src/ is not on the include path of programs that install the library;
// - every module-named DEPS entry is included by some file of the module;
// - an executable (apps/, data_tools/) includes only modules it links: its
//   FLAT_MODULES_<tool> and their DEPS, transitively (it links them PUBLIC);
// - every folder under src/ and include/flat/ is a declared module.
// Tests (tests/<m>/) are out of scope: they link extra modules on purpose.
#pragma once
#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace flat::layering {

// module -> its DEPS that are modules (flat_mod_<x> -> x), declaration order.
using DepsMap = std::map<std::string, std::vector<std::string>>;

struct ModuleMap {
  DepsMap deps;                           // flat_add_module(<m> DEPS ...)
  std::vector<std::string> order;         // modules in declaration order
  std::map<std::string, std::vector<std::string>> tool_modules;  // FLAT_MODULES_<tool>
};

// One finding: where, and what is wrong (with the module's DEPS).
struct Violation {
  std::string file;  // relative to the source root
  int line = 0;      // 0: the file as a whole
  std::string message;
};

std::string to_string(const Violation& v);  // "file:line: message"

// Parses <root>/CMakeLists.txt; throws std::runtime_error naming the file.
ModuleMap read_module_map(const std::filesystem::path& root);

// Every include of every module and executable against the map.
std::vector<Violation> check_includes(const std::filesystem::path& root, const ModuleMap& map);

// The "| module | DEPS ..." table of <root>/docs/development.md against the
// map: each module once, with the same DEPS (order free).
std::vector<Violation> check_doc_table(const std::filesystem::path& root, const ModuleMap& map);

// The table as docs/development.md should have it, one row per module.
std::string doc_table(const ModuleMap& map);

}  // namespace flat::layering
