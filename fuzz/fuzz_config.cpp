// libFuzzer target: arbitrary bytes as a YAML config. The contract under test:
// config::parse either returns a struct or throws flat::Error (any other
// exception, a crash or a sanitizer report is a bug), and whatever it accepts
// survives a write -> read round trip unchanged.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstdio>
#include <string>
#include <vector>

#include "flat/core/config.h"
#include "flat/core/error.h"

namespace {

using namespace flat;

// A representative config: nested sections, a list of sections, required
// keys, every scalar type, lists, ranges and choices.
struct Item {
  std::string name;
  int count = 1;
  bool enabled = true;
  template <class V>
  void visit(V& v) {
    v.required("name", name, "item name");
    v.field("count", count, config::non_negative());
    v.field("enabled", enabled);
  }
};

struct Inner {
  std::string mode = "flat";
  double eps = 0.1;
  float scale = 1.0f;
  std::vector<double> weights{1.0, 0.5};
  template <class V>
  void visit(V& v) {
    v.field("mode", mode, config::one_of({"flat", "ts", "none"}));
    v.field("eps", eps, config::range(0.0, 1.0));
    v.field("scale", scale, config::positive());
    v.field("weights", weights);
  }
};

struct Outer {
  int seed = 0;
  int64_t steps = 100;
  std::string name = "run";
  Inner inner;
  Inner other;
  std::vector<Item> items;
  std::vector<int> ids;
  std::vector<int64_t> big;
  std::vector<float> scales;
  std::vector<std::string> tags;
  template <class V>
  void visit(V& v) {
    v.field("seed", seed);
    v.required("steps", steps, config::positive());
    v.field("name", name);
    v.section("inner", inner);
    v.section("other", other);
    v.list("items", items);
    v.field("ids", ids);
    v.field("big", big);
    v.field("scales", scales);
    v.field("tags", tags);
  }
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  Outer parsed;
  try {
    parsed = config::parse<Outer>(text, "fuzz.yaml");
  } catch (const flat::Error&) {
    return 0;  // rejected with a message: the expected outcome for most inputs
  }
  // Accepted: what we write must read back to the same config.
  std::string first;
  try {
    first = config::to_yaml(parsed);
  } catch (const flat::Error&) {
    return 0;  // e.g. a string the emitter cannot write; reported, not a crash
  }
  const std::string second = config::to_yaml(config::parse<Outer>(first, "fuzz round trip"));
  if (first != second) {
    std::fprintf(stderr, "round trip changed the config:\n--- first\n%s--- second\n%s", first.c_str(), second.c_str());
    std::abort();
  }
  return 0;
}
