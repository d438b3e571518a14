// YAML configs mapped to typed, validated structs.
//
// A config struct lists its fields once, in a visit() member; the same list
// drives reading (with validation and unknown-key detection), writing the
// effective config, and --set overrides:
//
//   struct RasterConfig {
//     std::string window = "flat";
//     double eps = 0.1;
//     template <class V> void visit(V& v) {
//       v.field("window", window, config::one_of({"flat", "ts"}), "window function");
//       v.field("eps", eps, config::range(0.0, 1.0), "support beyond the edge, in inradii");
//     }
//   };
//   auto cfg = config::load<TrainConfig>("stage1.yaml", {"raster.eps=0.05"});
//   config::save(cfg, run.config_file());
//
// Errors are flat::Error: "<file>: 'raster.eps': expected a number in [0, 1], got '2'"
// for wrong types, out-of-range values, missing required keys, unknown keys.
#pragma once
#include <functional>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "flat/core/error.h"

namespace flat::config {

// A validation rule: returns "" when the value is fine, else what was expected.
struct Check {
  std::function<std::string(double)> number;              // for numeric fields
  std::function<std::string(const std::string&)> text;    // for string fields
};
Check range(double lo, double hi);       // lo <= x <= hi
Check positive();                        // x > 0
Check non_negative();                    // x >= 0
Check one_of(std::vector<std::string> choices);

// Context of one node: the file it came from and its dotted key path.
struct Where {
  std::string file;
  std::string path;  // "" at the root, else "a.b"
  std::string key(const std::string& k) const { return path.empty() ? k : path + "." + k; }
};

// Scalar conversions (defined in config.cpp). Throw flat::Error naming where.key.
void read_value(const YAML::Node& n, bool& out, const Where& w, const std::string& key);
void read_value(const YAML::Node& n, int& out, const Where& w, const std::string& key);
void read_value(const YAML::Node& n, int64_t& out, const Where& w, const std::string& key);
void read_value(const YAML::Node& n, double& out, const Where& w, const std::string& key);
void read_value(const YAML::Node& n, float& out, const Where& w, const std::string& key);
void read_value(const YAML::Node& n, std::string& out, const Where& w, const std::string& key);
void read_value(const YAML::Node& n, std::vector<int>& out, const Where& w, const std::string& key);
void read_value(const YAML::Node& n, std::vector<int64_t>& out, const Where& w, const std::string& key);
void read_value(const YAML::Node& n, std::vector<double>& out, const Where& w, const std::string& key);
void read_value(const YAML::Node& n, std::vector<float>& out, const Where& w, const std::string& key);
void read_value(const YAML::Node& n, std::vector<std::string>& out, const Where& w, const std::string& key);

// Apply a check to a value that was read; throws naming where.key.
void apply_check(const Check& c, double value, const Where& w, const std::string& key);
void apply_check(const Check& c, const std::string& value, const Where& w, const std::string& key);
void apply_check(const Check& c, bool value, const Where& w, const std::string& key);
template <class T>
void apply_check(const Check& c, const std::vector<T>& values, const Where& w, const std::string& key) {
  for (const auto& v : values) apply_check(c, v, w, key);
}
inline void apply_check(const Check& c, int value, const Where& w, const std::string& key) {
  apply_check(c, double(value), w, key);
}
inline void apply_check(const Check& c, int64_t value, const Where& w, const std::string& key) {
  apply_check(c, double(value), w, key);
}
inline void apply_check(const Check& c, float value, const Where& w, const std::string& key) {
  apply_check(c, double(value), w, key);
}

// A config struct may have `void check() const` for cross-field rules (e.g.
// depth_far > depth_near). The reader runs it once for every struct it fills,
// whether or not the YAML has that section (defaults are checked too), and
// prefixes the message with the file and the section's key path. Apps never
// call check() by hand.
namespace detail {
template <class S, class = void>
struct has_check : std::false_type {};
template <class S>
struct has_check<S, std::void_t<decltype(std::declval<const S&>().check())>> : std::true_type {};
}  // namespace detail

[[noreturn]] void rethrow_checked(const Where& where, const std::string& message);

template <class S>
void run_check(const S& s, const Where& where) {
  if constexpr (detail::has_check<S>::value) {
    try {
      s.check();
    } catch (const Error& e) {
      rethrow_checked(where, e.what());
    }
  }
}

// Walks a struct's visit() against a YAML map.
class Reader {
 public:
  Reader(YAML::Node node, Where where);

  template <class T>
  void field(const char* key, T& value, const Check& check = {}, const char* help = "") {
    (void)help;
    YAML::Node n = lookup(key);
    if (!n) return;  // keep the default
    read_value(n, value, where_, key);
    apply_check(check, value, where_, key);
  }
  template <class T>
  void field(const char* key, T& value, const char* help) { field(key, value, Check{}, help); }

  template <class T>
  void required(const char* key, T& value, const Check& check = {}, const char* help = "") {
    if (!lookup(key)) missing(key, help);
    field(key, value, check, help);
  }
  template <class T>
  void required(const char* key, T& value, const char* help) { required(key, value, Check{}, help); }

  template <class S>
  void section(const char* key, S& sub) {
    YAML::Node n = lookup(key);
    const Where where{where_.file, where_.key(key)};
    if (n) {
      Reader r(n, where);
      sub.visit(r);
      r.finish();
    }
    run_check(sub, where);
  }

  template <class S>
  void list(const char* key, std::vector<S>& items) {
    YAML::Node n = lookup(key);
    if (!n) return;
    expect_sequence(n, key);
    items.clear();
    for (size_t i = 0; i < n.size(); ++i) {
      S item{};
      Reader r(n[i], Where{where_.file, where_.key(key) + "[" + std::to_string(i) + "]"});
      item.visit(r);
      r.finish();
      run_check(item, Where{where_.file, where_.key(key) + "[" + std::to_string(i) + "]"});
      items.push_back(std::move(item));
    }
  }

  // Throws on keys present in the YAML map that no field consumed.
  void finish() const;

 private:
  YAML::Node lookup(const char* key);  // records the key as known
  [[noreturn]] void missing(const char* key, const char* help) const;
  void expect_sequence(const YAML::Node& n, const char* key) const;
  YAML::Node node_;
  Where where_;
  std::vector<std::string> known_;
};

// Walks a struct's visit() applying each field's declared check to the value it
// holds: the ranges written once in visit() also guard structs built in code
// (e.g. render::RasterSettings handed to rasterize()), so check() keeps only
// the cross-field rules. Sections and lists are walked too, and their check()
// runs. Errors read like a config's: "<what>: '<key>': expected ..., got ...".
class Validator {
 public:
  explicit Validator(Where where) : where_(std::move(where)) {}
  template <class T>
  void field(const char* key, const T& value, const Check& check = {}, const char* = "") {
    apply_check(check, value, where_, key);
  }
  template <class T>
  void field(const char* key, const T& value, const char* help) { field(key, value, Check{}, help); }
  template <class T>
  void required(const char* key, const T& value, const Check& check = {}, const char* help = "") {
    field(key, value, check, help);
  }
  template <class T>
  void required(const char* key, const T& value, const char* help) { field(key, value, Check{}, help); }
  template <class S>
  void section(const char* key, S& sub) {
    const Where where{where_.file, where_.key(key)};
    Validator v(where);
    sub.visit(v);
    run_check(sub, where);
  }
  template <class S>
  void list(const char* key, std::vector<S>& items) {
    for (size_t i = 0; i < items.size(); ++i) {
      const Where where{where_.file, where_.key(key) + "[" + std::to_string(i) + "]"};
      Validator v(where);
      items[i].visit(v);
      run_check(items[i], where);
    }
  }

 private:
  Where where_;
};

// The declared checks of every field of s (not s.check() itself, which calls
// this for its own fields); `what` names s in errors.
template <class S>
void validate_fields(const S& s, const std::string& what) {
  S copy = s;  // visit() is written for readers that fill the struct
  Validator v(Where{what, ""});
  copy.visit(v);
}

// Numbers as the shortest text that reads back to the same value ("0.1",
// where yaml-cpp would write "0.10000000000000001"); other types pass through.
std::string number_to_yaml(double x);
std::string number_to_yaml(float x);
inline std::string to_yaml_scalar(double x) { return number_to_yaml(x); }
inline std::string to_yaml_scalar(float x) { return number_to_yaml(x); }
template <class T>
const T& to_yaml_scalar(const T& x) { return x; }

// Walks a struct's visit() to produce YAML (the effective config).
class Writer {
 public:
  YAML::Node node{YAML::NodeType::Map};
  template <class T>
  void field(const char* key, const T& value, const Check& = {}, const char* = "") { node[key] = to_yaml_scalar(value); }
  template <class T>
  void field(const char* key, const T& value, const char*) { node[key] = to_yaml_scalar(value); }
  template <class T>
  void required(const char* key, const T& value, const Check& = {}, const char* = "") { node[key] = to_yaml_scalar(value); }
  template <class T>
  void required(const char* key, const T& value, const char*) { node[key] = to_yaml_scalar(value); }
  // Lists of numbers or names print on one line: "views: [0, 4, 8]".
  template <class T>
  void field(const char* key, const std::vector<T>& value, const Check& = {}, const char* = "") { flow(key, value); }
  template <class T>
  void field(const char* key, const std::vector<T>& value, const char*) { flow(key, value); }
  template <class T>
  void required(const char* key, const std::vector<T>& value, const Check& = {}, const char* = "") { flow(key, value); }
  template <class T>
  void required(const char* key, const std::vector<T>& value, const char*) { flow(key, value); }
  template <class S>
  void section(const char* key, S& sub) {
    Writer w;
    sub.visit(w);
    node[key] = w.node;
  }
  template <class S>
  void list(const char* key, std::vector<S>& items) {
    YAML::Node seq(YAML::NodeType::Sequence);
    for (auto& item : items) {
      Writer w;
      item.visit(w);
      seq.push_back(w.node);
    }
    node[key] = seq;
  }

 private:
  template <class T>
  void flow(const char* key, const std::vector<T>& value) {
    YAML::Node seq(YAML::NodeType::Sequence);
    for (const auto& v : value) seq.push_back(to_yaml_scalar(v));
    seq.SetStyle(YAML::EmitterStyle::Flow);
    node[key] = seq;
  }
};

// Walks a struct's visit() to list every key with its default and help text
// (--help-config, docs/config.md). Lists of sections show their item's keys
// under "name[].".
class Describer {
 public:
  struct Row {
    std::string key, value, help;
  };
  std::vector<Row> rows;
  explicit Describer(std::string prefix = "") : prefix_(std::move(prefix)) {}

  template <class T>
  void field(const char* key, const T& value, const Check& = {}, const char* help = "") { add(key, text(value), help); }
  template <class T>
  void field(const char* key, const T& value, const char* help) { add(key, text(value), help); }
  template <class T>
  void required(const char* key, const T&, const Check& = {}, const char* help = "") { add(key, "(required)", help); }
  template <class T>
  void required(const char* key, const T&, const char* help) { add(key, "(required)", help); }
  template <class S>
  void section(const char* key, S& sub) {
    Describer d(prefix_ + key + ".");
    sub.visit(d);
    rows.insert(rows.end(), d.rows.begin(), d.rows.end());
  }
  template <class S>
  void list(const char* key, std::vector<S>&) {
    S item{};
    Describer d(prefix_ + key + "[].");
    item.visit(d);
    rows.insert(rows.end(), d.rows.begin(), d.rows.end());
  }
  // "| key | default | meaning |" rows.
  std::string markdown() const;

 private:
  std::string prefix_;
  void add(const char* key, std::string value, const char* help) {
    rows.push_back({prefix_ + key, std::move(value), help ? help : ""});
  }
  template <class T>
  static std::string text(const T& value) {
    Writer w;
    w.field("v", value);
    return emit(w.node["v"]);
  }
  static std::string emit(const YAML::Node& node);
};

// Parse a YAML file or text (throws flat::Error with file, line and column),
// then apply "a.b.c=value" overrides (value parsed as YAML; an override whose
// path does not lead through maps is an error naming the override).
YAML::Node load_yaml_file(const std::string& file);
YAML::Node load_yaml_text(const std::string& text, const std::string& label);
void apply_overrides(YAML::Node& root, const std::vector<std::string>& overrides, const std::string& label);

template <class S>
S from_yaml(YAML::Node root, const std::string& label) {
  if (!root.IsMap() && !root.IsNull()) fail(label + ": top level must be a map of keys");
  S s{};
  Reader r(root, Where{label, ""});
  s.visit(r);
  r.finish();
  run_check(s, Where{label, ""});
  return s;
}

// Layers `overlay` over `base`: maps merge key by key (recursively), any other
// value (a number, a text, a list) in the overlay replaces the base's.
YAML::Node merge(const YAML::Node& base, const YAML::Node& overlay);

// The effective config of a program with built-in defaults: `defaults` (YAML
// text, labelled `defaults_label`), then each file in order layered over it,
// then the --set overrides. Errors name the file a bad value came from where
// one file gave it, else the chain of labels.
template <class S>
S load_layered(const std::string& defaults, const std::string& defaults_label, const std::vector<std::string>& files,
               const std::vector<std::string>& overrides = {}) {
  YAML::Node root = load_yaml_text(defaults, defaults_label);
  std::string label = files.empty() ? defaults_label : "";
  for (const auto& f : files) {
    root = merge(root, load_yaml_file(f));
    label += (label.empty() ? "" : " + ") + f;
  }
  if (files.size() == 1) label = files[0];
  apply_overrides(root, overrides, label);
  return from_yaml<S>(root, label);
}

template <class S>
S load(const std::string& file, const std::vector<std::string>& overrides = {}) {
  YAML::Node root = load_yaml_file(file);
  apply_overrides(root, overrides, file);
  return from_yaml<S>(root, file);
}

template <class S>
S parse(const std::string& text, const std::string& label, const std::vector<std::string>& overrides = {}) {
  YAML::Node root = load_yaml_text(text, label);
  apply_overrides(root, overrides, label);
  return from_yaml<S>(root, label);
}

template <class S>
std::string to_yaml(S s) {
  Writer w;
  s.visit(w);
  YAML::Emitter out;
  out << w.node;
  if (!out.good()) fail("config: cannot write the effective config as YAML: " + out.GetLastError());
  return std::string(out.c_str()) + "\n";
}

// Writes the effective config atomically.
void save_text(const std::string& file, const std::string& yaml);
template <class S>
void save(const S& s, const std::string& file) { save_text(file, to_yaml(s)); }

}  // namespace flat::config
