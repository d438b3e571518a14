// "No driver function over 80 lines" (docs/development.md) held on the
// sources of the driver modules: infer, mesh, eval and train. A long driver
// is split along its seams into named steps, so that each step can be read,
// and tested, on its own. The scan (tests/layering/function_length.h) is
// probed on small texts first, so that a pass means something.
#include <string>
#include <vector>

#include "catch.h"
#include "layering/function_length.h"

using namespace flat::layering;

namespace {

constexpr int kLimit = 80;

// A function whose body is `lines` lines long, its braces included.
std::string function_of(const std::string& name, int lines) {
  std::string s = "void " + name + "() {\n";
  for (int k = 0; k < lines - 2; ++k) s += "  step();\n";
  return s + "}\n";
}

std::vector<std::string> names(const std::vector<FunctionSpan>& spans) {
  std::vector<std::string> out;
  for (const auto& s : spans) out.push_back(s.name);
  return out;
}

}  // namespace

TEST_CASE("no function in src/infer, src/mesh, src/eval and src/train is over 80 lines", "[core][layering][function_length]") {
  const auto spans = scan_folders(FLAT_SOURCE_DIR, {"src/infer", "src/mesh", "src/eval", "src/train"});
  // The scan found the drivers at all (a broken scan finds nothing and passes).
  REQUIRE(spans.size() > 100);
  std::string over;
  for (const auto& s : spans)
    if (s.lines() > kLimit) over += to_string(s, kLimit) + "\n";
  INFO("split these along their seams:\n" << over);
  CHECK(over.empty());
}

TEST_CASE("the function-length scan measures bodies and is not fooled by comments, literals or initialisers",
          "[core][layering][function_length]") {
  SECTION("a body's lines are its '{' line to its '}' line") {
    const auto spans = function_spans(function_of("at_limit", kLimit) + function_of("over", kLimit + 1), "x.cpp");
    REQUIRE(spans.size() == 2);
    CHECK(spans[0].name == "at_limit");
    CHECK(spans[0].lines() == kLimit);
    CHECK(spans[0].open_line == 1);
    CHECK(spans[1].lines() == kLimit + 1);
    CHECK(spans[1].open_line == kLimit + 1);
    CHECK(to_string(spans[1], kLimit) == "x.cpp:81: over is 81 lines (limit 80)");
  }
  SECTION("braces in comments, strings, characters, raw strings and directives do not count") {
    const std::string text =
        "#define OPEN {\n"
        "#define LONG(x) \\\n  { x\n"
        "namespace a {  // { a comment\n"
        "/* } a block comment { */\n"
        "int f() {\n"
        "  const char* s = \"}\\\"}\";\n"
        "  char c = '}'; char d = '\\'';\n"
        "  auto r = R\"x(} \" })x\";\n"
        "  long n = 1'000'000;\n"
        "  return 0;\n"
        "}\n"
        "}  // namespace a\n";
    const auto spans = function_spans(text, "x.cpp");
    REQUIRE(spans.size() == 1);
    CHECK(spans[0].name == "f");
    CHECK(spans[0].open_line == 6);
    CHECK(spans[0].close_line == 12);
  }
  SECTION("members, constructors with brace initialisers, templates, operators and lambdas") {
    const std::string text =
        "namespace n {\n"
        "struct S : Base {\n"                                   // 2
        "  S(int a) : a_{a}, b_(Opts{1, 2}), c_{} {\n"          // 3
        "    go();\n"
        "  }\n"                                                 // 5
        " public:\n"
        "  int get() const { return a_; }\n"                    // 7
        "  bool operator==(const S& o) const { return a_ == o.a_; }\n"
        "  int a_ = 0;\n"
        "  struct Inner { void in() {} };\n"                    // 10
        "};\n"
        "template <typename T, int N = 3>\n"
        "T::Out Wrap<T>::apply(const Opts& o = {}) {\n"         // 13
        "  return {};\n"
        "}\n"
        "const auto kTable = std::vector<int>{1, 2,\n"          // 16: an initialiser, not a function
        "  3};\n"
        "const std::map<int, int> kMap = {{1, f(2)}};\n"
        "enum class E { a, b };\n"
        "auto lambda = [](int x) {\n"                           // 20
        "  return x;\n"
        "};\n"
        "extern \"C\" {\n"
        "void c_api(void) {\n"                                  // 24
        "  auto inner = [] { return 1; };\n"
        "}\n"
        "}\n"
        "}  // namespace n\n";
    const auto spans = function_spans(text, "x.cpp");
    CHECK(names(spans) == std::vector<std::string>{"S", "get", "operator==", "in", "Wrap<T>::apply",
                                                   "lambda (lambda)", "c_api"});
    REQUIRE(spans.size() == 7);
    CHECK(spans[0].open_line == 3);
    CHECK(spans[0].close_line == 5);
    CHECK(spans[4].open_line == 13);
    CHECK(spans[4].close_line == 15);
    CHECK(spans[5].open_line == 20);
    CHECK(spans[5].close_line == 22);
    CHECK(spans[6].lines() == 3);
  }
  SECTION("an unbalanced brace is an error naming the file and line") {
    CHECK_THROWS_WITH(function_spans("namespace a {\nvoid f() {\n", "bad.cpp"),
                      FLAT_CONTAINS("bad.cpp:2: this '{' is never closed"));
    CHECK_THROWS_WITH(function_spans("void f() {}\n}\n", "bad.cpp"),
                      FLAT_CONTAINS("bad.cpp:2: a '}' closes nothing"));
  }
}
