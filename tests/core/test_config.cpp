// Config system: malformed files meet specific errors naming file and key;
// save -> load round-trips every field; overrides change and are validated.
#include <cmath>
#include <cstdint>
#include <fstream>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "flat/core/config.h"
#include "support/error_of.h"
#include "test_support.h"

namespace {

using namespace flat;

struct ViewCfg {
  std::string name;
  int index = 0;
  double weight = 1.0;
  template <class V>
  void visit(V& v) {
    v.required("name", name, "view name");
    v.field("index", index, config::non_negative(), "frame index");
    v.field("weight", weight, config::positive(), "loss weight");
  }
};

struct RasterCfg {
  std::string window = "flat";
  double eps = 0.1;
  float sigma = 0.5f;
  bool antialias = true;
  template <class V>
  void visit(V& v) {
    v.field("window", window, config::one_of({"flat", "ts"}), "window function");
    v.field("eps", eps, config::range(0.0, 1.0), "support beyond the edge");
    v.field("sigma", sigma, config::positive());
    v.field("antialias", antialias, "blend edges");
  }
};

struct OptimCfg {
  double lr = 1e-4;
  int64_t steps = 1000;
  std::vector<double> betas{0.9, 0.999};
  std::vector<int> milestones;
  template <class V>
  void visit(V& v) {
    v.field("lr", lr, config::positive());
    v.field("steps", steps, config::non_negative());
    v.field("betas", betas, config::range(0.0, 1.0));
    v.field("milestones", milestones);
  }
};

struct TestCfg {
  std::string name;
  int seed = 0;
  RasterCfg raster;
  RasterCfg preview;
  OptimCfg optim;
  std::vector<ViewCfg> views{ViewCfg{"front", 0, 1.0}};
  std::vector<std::string> tags{"a"};
  std::vector<float> scales{1.0f};
  std::vector<int64_t> ids;
  template <class V>
  void visit(V& v) {
    v.required("name", name, "run name");
    v.field("seed", seed);
    v.section("raster", raster);
    v.section("preview", preview);
    v.section("optim", optim);
    v.list("views", views);
    v.field("tags", tags);
    v.field("scales", scales, config::positive());
    v.field("ids", ids);
  }
};

void write_text(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

using flat::test::error_of;

struct BadCase {
  const char* name;
  const char* yaml;  // nullptr: the file does not exist
  std::vector<std::string> overrides;
  std::vector<std::string> expect;  // substrings of the error message
};

const std::vector<BadCase>& bad_cases() {
  static const std::vector<BadCase> cases = {
      {"unknown_key_suggestion", "name: x\nraster:\n  esp: 0.2\n", {},
       {"unknown key 'raster.esp' (line 3, column 3)", "did you mean 'raster.eps'?"}},
      {"unknown_key_in_list_item", "name: x\nviews:\n  - name: a\n    wieght: 2\n", {},
       {"unknown key 'views[0].wieght'", "did you mean 'views[0].weight'?"}},
      {"unknown_key_no_suggestion", "name: x\nzzzzzz: 1\n", {}, {"unknown key 'zzzzzz'"}},
      {"int_wrong_type", "name: x\nseed: abc\n", {}, {"'seed': expected an integer, got 'abc' (line 2, column 7)"}},
      {"int_rejects_fraction", "name: x\nseed: 1.5\n", {}, {"'seed': expected an integer, got '1.5'"}},
      {"int_out_of_range", "name: x\nseed: 3000000000\n", {},
       {"'seed': expected an integer in [-2147483648, 2147483647], got '3000000000'"}},
      {"int64_list_out_of_range", "name: x\nids: [1, 99999999999999999999]\n", {},
       {"'ids[1]': expected an integer, got '99999999999999999999'"}},
      {"int_plus_minus", "name: x\nseed: +-1\n", {}, {"'seed': expected an integer, got '+-1'"}},
      {"string_null", "name:\nseed: 1\n", {}, {"'name': expected a string", "got nothing (null)"}},
      {"bool_wrong_type", "name: x\nraster:\n  antialias: yes\n", {},
       {"'raster.antialias': expected true or false, got 'yes'"}},
      {"double_wrong_type", "name: x\nraster:\n  eps: fast\n", {}, {"'raster.eps': expected a finite number, got 'fast'"}},
      {"double_nan", "name: x\noptim:\n  lr: .nan\n", {}, {"'optim.lr': expected a finite number, got '.nan'"}},
      {"double_inf", "name: x\noptim:\n  lr: inf\n", {}, {"'optim.lr': expected a finite number, got 'inf'"}},
      {"double_quoted", "name: x\nraster:\n  eps: \"0.5\"\n", {},
       {"'raster.eps': expected a finite number, got '0.5' (a quoted string)"}},
      {"float_overflow", "name: x\nraster:\n  sigma: 1e300\n", {}, {"'raster.sigma': expected a number within float range"}},
      {"out_of_range", "name: x\nraster:\n  eps: 2\n", {}, {"'raster.eps': expected a number in [0, 1], got '2'"}},
      {"not_positive", "name: x\noptim:\n  lr: 0\n", {}, {"'optim.lr': expected a number > 0, got '0'"}},
      {"list_element_out_of_range", "name: x\noptim:\n  betas: [0.9, 1.5]\n", {},
       {"'optim.betas': expected a number in [0, 1], got '1.5'"}},
      {"list_element_wrong_type", "name: x\noptim:\n  betas: [0.9, x]\n", {},
       {"'optim.betas[1]': expected a finite number, got 'x'"}},
      {"not_one_of", "name: x\nraster:\n  window: box\n", {},
       {"'raster.window': expected one of {flat, ts}, got 'box'"}},
      {"missing_required", "seed: 1\n", {}, {"missing required key 'name' (run name)"}},
      {"missing_required_in_list", "name: x\nviews:\n  - index: 2\n", {},
       {"missing required key 'views[0].name' (view name)"}},
      {"string_given_map", "name: {a: 1}\n", {}, {"'name': expected a string", "got a map"}},
      {"yaml_syntax_error", "name: x\nseed: 1\n  bad: 2\n", {}, {"YAML syntax error at line 3, column 6"}},
      {"yaml_unknown_anchor", "name: x\nseed: 1\nraster: *nope\n", {}, {"YAML syntax error at line 3"}},
      {"top_level_list", "- a\n- b\n", {}, {"top level must be a map of keys"}},
      {"top_level_scalar", "just text\n", {}, {"top level must be a map of keys"}},
      {"section_not_map", "name: x\nraster: [1, 2]\n", {},
       {"'raster': expected a section (a map of keys), got a list (line 2, column 9)"}},
      {"section_scalar", "name: x\noptim: 3\n", {}, {"'optim': expected a section (a map of keys), got '3'"}},
      {"list_not_sequence", "name: x\nviews: abc\n", {}, {"'views': expected a list, got 'abc'"}},
      {"list_item_not_map", "name: x\nviews:\n  - 3\n", {}, {"'views[0]': expected a section (a map of keys), got '3'"}},
      {"vector_not_sequence", "name: x\noptim:\n  milestones: 5\n", {}, {"'optim.milestones': expected a list, got '5'"}},
      {"duplicate_key", "name: x\nseed: 1\nseed: 2\n", {}, {"duplicate key 'seed' (line 3, column 1), first given (line 2, column 1)"}},
      {"duplicate_key_nested", "name: x\nraster:\n  eps: 0.1\n  eps: 0.2\n", {}, {"duplicate key 'raster.eps'"}},
      {"override_no_equals", "name: x\n", {"seed"}, {"override 'seed': expected key.path=value"}},
      {"override_empty_key", "name: x\n", {"=3"}, {"override '=3': empty key"}},
      {"override_empty_segment", "name: x\n", {"raster..eps=3"}, {"override 'raster..eps=3': empty name"}},
      {"override_through_scalar", "name: x\nseed: 1\n", {"seed.x=1"},
       {"override 'seed.x=1': 'seed' is '1'", "not a section"}},
      {"override_through_list", "name: x\nviews: []\n", {"views.x=1"},
       {"override 'views.x=1': 'views' is a list", "not a section"}},
      {"override_bad_value", "name: x\n", {"tags=[a, b"}, {"override 'tags=[a, b': value is not valid YAML"}},
      {"override_out_of_range", "name: x\n", {"raster.eps=5"}, {"'raster.eps': expected a number in [0, 1], got '5'"}},
      {"override_unknown_key", "name: x\n", {"raster.esp=0.5"}, {"unknown key 'raster.esp'", "did you mean 'raster.eps'?"}},
      {"missing_file", nullptr, {}, {"config file not found"}},
  };
  return cases;
}

TEST_CASE("config: each malformed file gets its specific error naming file and key", "[config]") {
  const auto dir = flat::test::scratch_dir("config_bad_cases");
  REQUIRE(bad_cases().size() >= 10);
  for (const auto& c : bad_cases()) {
    const std::string file = (dir / (std::string(c.name) + ".yaml")).string();
    if (c.yaml) write_text(file, c.yaml);
    const std::string message = error_of([&] { config::load<TestCfg>(file, c.overrides); });
    INFO("case " << c.name << ": " << message);
    CHECK(message.find(file) != std::string::npos);  // names the file
    for (const auto& expected : c.expect) CHECK(message.find(expected) != std::string::npos);
  }
}

TEST_CASE("config: an unknown key far from every known key gets no suggestion", "[config]") {
  const auto message = error_of([] { config::parse<TestCfg>("name: x\nzzzzzz: 1\n", "t.yaml"); });
  CHECK(message.find("unknown key 'zzzzzz'") != std::string::npos);
  CHECK(message.find("did you mean") == std::string::npos);
}

TEST_CASE("config: every unknown key is listed, each with its path", "[config]") {
  const auto message = error_of([] { config::parse<TestCfg>("name: x\nsed: 1\nrastr: {}\n", "t.yaml"); });
  CHECK(message.find("t.yaml: unknown key 'sed' (line 2, column 1), did you mean 'seed'?") != std::string::npos);
  CHECK(message.find("t.yaml: unknown key 'rastr' (line 3, column 1), did you mean 'raster'?") != std::string::npos);
  // Nested sections name the full path of their unknown keys.
  const auto nested = error_of([] { config::parse<TestCfg>("name: x\nraster:\n  windw: ts\n", "t.yaml"); });
  CHECK(nested.find("unknown key 'raster.windw' (line 3, column 3), did you mean 'raster.window'?") != std::string::npos);
}

TEST_CASE("config: absent, empty and partial sections keep their defaults", "[config]") {
  auto cfg = config::parse<TestCfg>("name: run\nraster:\noptim:\n  lr: 0.5\n", "t.yaml");
  const TestCfg defaults{};
  CHECK(cfg.name == "run");
  CHECK(cfg.raster.window == defaults.raster.window);
  CHECK(cfg.raster.eps == defaults.raster.eps);
  CHECK(cfg.optim.lr == 0.5);
  CHECK(cfg.optim.steps == defaults.optim.steps);
  CHECK(cfg.optim.betas == defaults.optim.betas);
  REQUIRE(cfg.views.size() == 1);
  CHECK(cfg.views[0].name == "front");
  CHECK(cfg.tags == defaults.tags);
}

TEST_CASE("config: a list given in the file replaces the default list", "[config]") {
  auto cfg = config::parse<TestCfg>("name: run\nviews:\n  - name: a\n  - {name: b, index: 4, weight: 0.5}\n", "t.yaml");
  REQUIRE(cfg.views.size() == 2);
  CHECK(cfg.views[0].name == "a");
  CHECK(cfg.views[0].index == 0);  // item defaults come from ViewCfg{}
  CHECK(cfg.views[1].name == "b");
  CHECK(cfg.views[1].index == 4);
  CHECK(cfg.views[1].weight == 0.5);
  auto empty = config::parse<TestCfg>("name: run\nviews: []\n", "t.yaml");
  CHECK(empty.views.empty());
}

TEST_CASE("config: scalar spellings", "[config]") {
  auto cfg = config::parse<TestCfg>(
      "name: 123\nseed: -7\nraster: {antialias: False, eps: +0.5, sigma: 2}\noptim: {steps: 9007199254740993, lr: 1E-3}\n"
      "ids: [-9223372036854775808, 9223372036854775807]\n",
      "t.yaml");
  CHECK(cfg.name == "123");  // strings accept any scalar
  CHECK(cfg.seed == -7);
  CHECK(cfg.raster.antialias == false);
  CHECK(cfg.raster.eps == 0.5);
  CHECK(cfg.raster.sigma == 2.0f);
  CHECK(cfg.optim.steps == int64_t(9007199254740993LL));  // not routed through double
  CHECK(cfg.optim.lr == 1e-3);
  CHECK(cfg.ids == std::vector<int64_t>{std::numeric_limits<int64_t>::min(), std::numeric_limits<int64_t>::max()});
}

TestCfg unusual_config() {
  TestCfg s;
  s.name = "colon: and # hash, \"double\" and 'single' quotes\ttab\nnewline  trailing ";
  s.seed = -2147483647 - 1;
  s.raster.window = "ts";
  s.raster.eps = 1e-4;
  s.raster.sigma = 1.0f / 3.0f;
  s.raster.antialias = false;
  s.preview.eps = 1.0 / 3.0;
  s.preview.sigma = 0.1f;
  s.optim.lr = 0.1;
  s.optim.steps = 9007199254740993LL;
  s.optim.betas = {1.0 / 3.0, 0.1, 1e-4, 5e-324, 0.0};
  s.optim.milestones = {-3, 0, 2147483647};
  s.views = {ViewCfg{"", 1, 1e300}, ViewCfg{"~", 2, 2.5e-308}, ViewCfg{"null", 3, 0.30000000000000004}};
  s.tags = {"true", "123", "", " lead", "- dash", "[x]", "{y}", "*star", "&amp", "!bang", "%pct", "@at", "`tick",
            "é ü 漢字", "a: b", "#c", "'", "\""};
  s.scales = {0.1f, 1.0f / 3.0f, 3.4e38f, 1e-38f};
  s.ids = {std::numeric_limits<int64_t>::min(), 0, std::numeric_limits<int64_t>::max()};
  return s;
}

void check_equal(const RasterCfg& a, const RasterCfg& b) {
  CHECK(a.window == b.window);
  CHECK(a.eps == b.eps);
  CHECK(a.sigma == b.sigma);
  CHECK(a.antialias == b.antialias);
}

void check_equal(const TestCfg& a, const TestCfg& b) {
  CHECK(a.name == b.name);
  CHECK(a.seed == b.seed);
  check_equal(a.raster, b.raster);
  check_equal(a.preview, b.preview);
  CHECK(a.optim.lr == b.optim.lr);
  CHECK(a.optim.steps == b.optim.steps);
  CHECK(a.optim.betas == b.optim.betas);  // exact: the writer keeps full precision
  CHECK(a.optim.milestones == b.optim.milestones);
  REQUIRE(a.views.size() == b.views.size());
  for (size_t i = 0; i < a.views.size(); ++i) {
    CHECK(a.views[i].name == b.views[i].name);
    CHECK(a.views[i].index == b.views[i].index);
    CHECK(a.views[i].weight == b.views[i].weight);
  }
  CHECK(a.tags == b.tags);
  CHECK(a.scales == b.scales);
  CHECK(a.ids == b.ids);
}

TEST_CASE("config: save then load gives back every field exactly", "[config]") {
  const auto dir = flat::test::scratch_dir("config_round_trip");
  const std::string file = (dir / "sub" / "config.yaml").string();  // save creates the folder
  const TestCfg original = unusual_config();
  config::save(original, file);
  const auto loaded = config::load<TestCfg>(file);
  INFO(config::to_yaml(original));
  check_equal(loaded, original);
  CHECK(config::to_yaml(loaded) == config::to_yaml(original));

  // Defaults round-trip too (empty lists included).
  TestCfg defaults;
  defaults.name = "d";
  defaults.views.clear();
  check_equal(config::parse<TestCfg>(config::to_yaml(defaults), "defaults"), defaults);
}

TEST_CASE("config: overrides change values, build missing sections and are validated", "[config]") {
  const std::string base = "name: base\nseed: 1\nraster: &r\n  eps: 0.2\npreview: *r\n";
  auto cfg = config::parse<TestCfg>(
      base, "t.yaml",
      {"raster.eps=0.25", "optim.betas=[0.5, 0.6]", "optim.lr=3e-4", "views=[{name: a, index: 3}]", "name=\"x: y\"",
       "seed=5", "seed=6", "tags=[]", "raster.window=ts"});
  CHECK(cfg.raster.eps == 0.25);
  CHECK(cfg.raster.window == "ts");
  CHECK(cfg.preview.eps == 0.2);  // the override did not write through the YAML alias
  CHECK(cfg.preview.window == "flat");
  CHECK(cfg.optim.betas == std::vector<double>{0.5, 0.6});
  CHECK(cfg.optim.lr == 3e-4);  // section absent from the file: created by the override
  REQUIRE(cfg.views.size() == 1);
  CHECK(cfg.views[0].name == "a");
  CHECK(cfg.views[0].index == 3);
  CHECK(cfg.name == "x: y");
  CHECK(cfg.seed == 6);  // the last override wins
  CHECK(cfg.tags.empty());

  // Overrides on an empty document build it from nothing.
  auto from_empty = config::parse<TestCfg>("", "empty.yaml", {"name=n", "optim.lr=0.5"});
  CHECK(from_empty.name == "n");
  CHECK(from_empty.optim.lr == 0.5);

  // A bad override value names the key, with no misleading file line.
  const auto message = error_of([&] { config::parse<TestCfg>(base, "t.yaml", {"optim.steps=many"}); });
  CHECK(message.find("t.yaml: 'optim.steps': expected an integer, got 'many'") != std::string::npos);
  CHECK(message.find("(line") == std::string::npos);
  const auto range = error_of([&] { config::parse<TestCfg>(base, "t.yaml", {"raster.eps=1.5"}); });
  CHECK(range.find("'raster.eps': expected a number in [0, 1], got '1.5'") != std::string::npos);
}

TEST_CASE("config: writer output is readable YAML with flow lists", "[config]") {
  TestCfg s;
  s.name = "n";
  s.optim.milestones = {1, 2, 3};
  const std::string text = config::to_yaml(s);
  CHECK(text.find("milestones: [1, 2, 3]") != std::string::npos);
  CHECK(text.find("eps: 0.1\n") != std::string::npos);  // shortest text that reads back exactly
  CHECK(text.find("betas: [0.9, 0.999]") != std::string::npos);
  CHECK(text.find("views:") != std::string::npos);
}

}  // namespace

namespace {
// A section with a cross-field rule, checked by the reader itself.
struct RangeCfg {
  double near = 1, far = 10;
  template <class V>
  void visit(V& v) {
    v.field("near", near, "near");
    v.field("far", far, "far");
  }
  void check() const { FLAT_CHECK(far > near, "'far' (" + std::to_string(far) + ") must exceed 'near'"); }
};
struct LayeredCfg {
  std::string name = "base";
  int64_t steps = 5;
  std::vector<int64_t> views = {1, 2};
  RangeCfg depth;
  template <class V>
  void visit(V& v) {
    v.field("name", name, "name");
    v.field("steps", steps, "steps");
    v.field("views", views, "views");
    v.section("depth", depth);
  }
};
}  // namespace

TEST_CASE("config: check() runs inside the reader, naming the section, present or not", "[config]") {
  const auto bad = error_of([] { config::parse<LayeredCfg>("depth: {near: 5, far: 2}\n", "t.yaml"); });
  CHECK(bad.find("t.yaml: 'depth': 'far'") != std::string::npos);
  // Defaults are checked too: an override alone can break them.
  const auto over = error_of([] { config::parse<LayeredCfg>("name: x\n", "t.yaml", {"depth.far=0.5"}); });
  CHECK(over.find("'depth'") != std::string::npos);
  CHECK_NOTHROW(config::parse<LayeredCfg>("name: x\n", "t.yaml"));
}

TEST_CASE("config: files layer over defaults key by key, lists replace, --set comes last", "[config]") {
  const auto dir = flat::test::scratch_dir("config_layered");
  const std::string file = (dir / "over.yaml").string();
  std::ofstream(file) << "views: [7]\ndepth: {far: 20}\n";
  const std::string defaults = "name: tiny\nsteps: 3\nviews: [1, 2, 3]\ndepth: {near: 2, far: 4}\n";
  auto cfg = config::load_layered<LayeredCfg>(defaults, "<defaults>", {file}, {"steps=9"});
  CHECK(cfg.name == "tiny");              // from the defaults
  CHECK(cfg.views == std::vector<int64_t>{7});  // the file's list replaces the default list
  CHECK(cfg.depth.near == 2);             // a sibling key of the file's survives
  CHECK(cfg.depth.far == 20);
  CHECK(cfg.steps == 9);                  // --set last
  std::ofstream(file) << "depth: {nearr: 1}\n";
  const auto typo = error_of([&] { config::load_layered<LayeredCfg>(defaults, "<defaults>", {file}); });
  CHECK(typo.find(file) != std::string::npos);
  CHECK(typo.find("depth.nearr") != std::string::npos);
}

TEST_CASE("config: errors give the real line and column, also through layering and --set", "[config]") {
  const auto dir = flat::test::scratch_dir("config_marks");
  const std::string file = (dir / "stage.yaml").string();
  // As flat_train reads a stage file: layered over defaults ("" or a text), then --set.
  write_text(file, "name: x\n# a comment\n\n\n\n\n\n\nsteps: many\n");
  for (const std::string defaults : {"", "name: tiny\nsteps: 3\n"}) {
    const auto msg = error_of([&] { config::load_layered<LayeredCfg>(defaults, "<defaults>", {file}, {"views=[3]"}); });
    INFO(msg);
    CHECK(msg.find("'steps': expected an integer, got 'many' (line 9, column 8)") != std::string::npos);
  }
  write_text(file, "name: x\nsteps: 1\nsteps: 2\n");
  for (const std::string defaults : {"", "steps: 3\n"}) {
    const auto msg = error_of([&] { config::load_layered<LayeredCfg>(defaults, "<defaults>", {file}); });
    INFO(msg);
    CHECK(msg.find("duplicate key 'steps' (line 3, column 1), first given (line 2, column 1)") != std::string::npos);
  }
  // A key inside a section that the defaults also give, and that a --set writes into.
  write_text(file, "name: x\ndepth:\n  far: 9\n  nearr: 1\n");
  const auto msg = error_of([&] {
    config::load_layered<LayeredCfg>("depth: {near: 2, far: 4}\n", "<defaults>", {file}, {"depth.far=7"});
  });
  INFO(msg);
  CHECK(msg.find("unknown key 'depth.nearr' (line 4, column 3)") != std::string::npos);
}

TEST_CASE("config: the describer lists every key with its default", "[config]") {
  LayeredCfg c;
  config::Describer d;
  c.visit(d);
  const std::string md = d.markdown();
  CHECK(md.find("| `depth.far` | `10` | far |") != std::string::npos);
  CHECK(md.find("| `views` | `[1, 2]` | views |") != std::string::npos);
}

TEST_CASE("config: validate_fields applies visit()'s checks to a struct built in code", "[config]") {
  TestCfg c;
  c.name = "run";
  config::validate_fields(c, "in code");  // the defaults pass
  c.optim.betas = {0.9, 1.5};
  REQUIRE_THROWS_WITH(config::validate_fields(c, "in code"),
                      FLAT_CONTAINS("in code: 'optim.betas': expected") && FLAT_CONTAINS("1.5"));
  c = TestCfg{};
  c.views[0].weight = -1;
  REQUIRE_THROWS_WITH(config::validate_fields(c, "in code"), FLAT_CONTAINS("'views[0].weight'"));
  c = TestCfg{};
  c.raster.window = "box";
  REQUIRE_THROWS_WITH(config::validate_fields(c, "in code"), FLAT_CONTAINS("'raster.window'"));
}
