// The module map enforced on the sources (tests/layering/module_map.h): every
// module includes only the modules of its DEPS, no module includes another
// one's private header, and docs/development.md's table is CMakeLists.txt's.
// The link-time probe (render_calls_train.cpp) is the CTest test "layering".
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

#include "catch.h"
#include "layering/module_map.h"

namespace fs = std::filesystem;
using namespace flat::layering;

namespace {

std::string listing(const std::vector<Violation>& vs) {
  std::string out;
  for (const auto& v : vs) out += to_string(v) + "\n";
  return out;
}

bool has(const std::vector<Violation>& vs, const std::string& where, const std::string& what) {
  for (const auto& v : vs)
    if (to_string(v).rfind(where, 0) == 0 && v.message.find(what) != std::string::npos) return true;
  return false;
}

void write(const fs::path& path, const std::string& text) {
  fs::create_directories(path.parent_path());
  std::ofstream(path) << text;
}

fs::path scratch(const std::string& name) {
  const char* env = std::getenv("FLAT_TEST_TMP");
  fs::path dir = fs::path(env ? env : (fs::temp_directory_path() / "flat_test_tmp").string()) / name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

}  // namespace

TEST_CASE("every module includes only the modules of its DEPS, and no private header of another", "[core][layering]") {
  const auto map = read_module_map(FLAT_SOURCE_DIR);
  const auto found = check_includes(FLAT_SOURCE_DIR, map);
  INFO(found.size() << " include(s) outside the module map:\n" << listing(found));
  CHECK(found.empty());
}

TEST_CASE("docs/development.md's module table is CMakeLists.txt's DEPS", "[core][layering]") {
  const auto map = read_module_map(FLAT_SOURCE_DIR);
  const auto found = check_doc_table(FLAT_SOURCE_DIR, map);
  INFO(listing(found) << "the table from CMakeLists.txt (flat_test_layering \"[.print]\" prints it):\n"
                      << doc_table(map));
  CHECK(found.empty());
}

// The map as docs/development.md should show it, printed to paste there.
TEST_CASE("print the module table", "[.print]") { std::cout << doc_table(read_module_map(FLAT_SOURCE_DIR)); }

// The checker on a tree made to break each rule once: it must name the file,
// the line, the include and the module's DEPS.
TEST_CASE("the include check fails on each kind of break", "[core][layering]") {
  const fs::path root = scratch("layering_probe");
  write(root / "CMakeLists.txt",
        "flat_add_module(a DEPS)\n"
        "flat_add_module(b DEPS flat_mod_a some_other_lib)  # a non-module DEPS entry is ignored\n"
        "flat_add_module(c DEPS flat_mod_a flat_mod_b)\n"
        "set(FLAT_MODULES_tool_b b)\n"
        "set(FLAT_MODULES_tool_c c)\n");
  write(root / "include/flat/a/a.h", "#pragma once\n");
  write(root / "src/a/a_private.h", "#pragma once\n");
  write(root / "src/a/a.cpp", "#include \"flat/a/a.h\"\n#include \"a/a_private.h\"\n\n#include \"flat/b/b.h\"\n");
  write(root / "include/flat/b/b.h", "#pragma once\n#include \"flat/a/a.h\"\n#include \"b/b_private.h\"\n");
  write(root / "src/b/b_private.h", "#pragma once\n");
  write(root / "src/b/cpu/local.h", "#pragma once\n");
  write(root / "src/b/b.cpp", "#include \"flat/b/b.h\"\n#include \"cpu/local.h\"\n#include \"a/a_private.h\"\n");
  write(root / "src/c/c.cpp", "  #  include <flat/a/a.h>\n// #include \"flat/b/b.h\"\n");
  write(root / "src/stray/stray.cpp", "#include \"flat/c/c.h\"\n");
  write(root / "apps/tool_b.cpp", "#include \"flat/a/a.h\"\n#include \"flat/c/c.h\"\n");
  write(root / "apps/tool_c/main.cpp", "#include \"flat/b/b.h\"\n");
  write(root / "apps/tool_x.cpp", "int main() {}\n");

  const auto map = read_module_map(root);
  REQUIRE(map.order == std::vector<std::string>{"a", "b", "c"});
  CHECK(map.deps.at("b") == std::vector<std::string>{"a"});
  const auto found = check_includes(root, map);
  INFO(listing(found));
  // a includes b, which is not in its (empty) DEPS.
  CHECK(has(found, "src/a/a.cpp:4: ", "module a (DEPS: (none)) includes \"flat/b/b.h\" of module b, which is not in its DEPS"));
  // b includes a's private header although a is in its DEPS.
  CHECK(has(found, "src/b/b.cpp:3: ", "includes \"a/a_private.h\", a private header of module a (src/a/)"));
  // A public header including a private one, even its own module's.
  CHECK(has(found, "include/flat/b/b.h:3: ", "public header of module b includes \"b/b_private.h\""));
  // c names b in its DEPS but includes nothing of it (a commented include does not count).
  CHECK(has(found, "CMakeLists.txt: ", "module c (DEPS: a, b) names flat_mod_b"));
  CHECK(has(found, "src/stray: ", "folder of no module"));
  // tool_b links b and a (b's DEPS): a is fine, c is not; tool_c links c, b, a.
  CHECK(has(found, "apps/tool_b.cpp:2: ", "executable tool_b (FLAT_MODULES_tool_b: b) includes \"flat/c/c.h\""));
  CHECK_FALSE(has(found, "apps/tool_b.cpp:1: ", ""));
  CHECK_FALSE(has(found, "apps/tool_c/", ""));
  CHECK(has(found, "apps/tool_x.cpp: ", "no set(FLAT_MODULES_tool_x"));
  // Allowed: own private headers, paths relative to the file, angle includes of a DEPS module.
  CHECK_FALSE(has(found, "src/a/a.cpp:2: ", ""));
  CHECK_FALSE(has(found, "src/b/b.cpp:2: ", ""));
  CHECK_FALSE(has(found, "src/c/", ""));
  CHECK(found.size() == 7);

  // The doc table: grouped rows and notes in parentheses are read; a wrong
  // row, an unknown module and a missing one are named.
  write(root / "docs/development.md",
        "| module | DEPS (the modules whose headers it includes) |\n|---|---|\n"
        "| a | none |\n"
        "| b, c | a (`some_other_lib`, not a module) |\n"
        "| d | a |\n");
  const auto doc = check_doc_table(root, map);
  INFO(listing(doc));
  CHECK(has(doc, "docs/development.md:4: ", "module table says c depends on a; CMakeLists.txt's DEPS: a, b"));
  CHECK(has(doc, "docs/development.md:5: ", "lists d, which CMakeLists.txt does not declare"));
  CHECK(doc.size() == 2);
  write(root / "docs/development.md",
        "| module | DEPS |\n|---|---|\n| a | none |\n| b | a |\n");
  CHECK(has(check_doc_table(root, map), "docs/development.md: ", "leaves out module c (DEPS: a, b)"));
}
