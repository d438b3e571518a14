// YAML configs -> typed, validated structs (see include/flat/core/config.h).
//
// Torch-free on purpose: the libFuzzer target builds this file alone with
// yaml-cpp, without the precompiled header, so every include is spelled out.
// Everything yaml-cpp can throw is turned into flat::Error here, so callers
// (and the fuzzer) only ever see flat::Error.
#include "flat/core/config.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>
#include <string>
#include <system_error>
#include <vector>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"

namespace flat::config {
namespace {

// " (line N, column C)" for nodes that came from a parsed file; "" for nodes
// built in code (overrides), whose place would mean nothing, and for empty
// values, which yaml-cpp marks at the token after them (often the next line).
std::string line_of(const YAML::Node& n) {
  const YAML::Mark m = n.Mark();
  if (n.IsNull() || m.is_null() || m.line < 0) return "";
  return " (line " + std::to_string(m.line + 1) + ", column " + std::to_string(m.column + 1) + ")";
}

// A copy of `n` whose maps are new nodes (writing into them never reaches
// the source, e.g. through an alias) while keys, scalars and lists are the
// source's own nodes, never written into: they keep their marks, so errors
// name the real line and column. (YAML::Clone marks every node it makes
// line 1, column 1.)
YAML::Node copy_tree(const YAML::Node& n) {
  if (!n.IsMap()) return n;
  YAML::Node m(YAML::NodeType::Map);
  for (const auto& kv : n) m.force_insert(kv.first, copy_tree(kv.second));
  return m;
}

// How a node that had the wrong type looks to the user: 'text', a list, a map.
std::string describe(const YAML::Node& n) {
  switch (n.Type()) {
    case YAML::NodeType::Sequence: return "a list";
    case YAML::NodeType::Map: return "a map";
    case YAML::NodeType::Null: return "nothing (null)";
    case YAML::NodeType::Undefined: return "nothing";
    case YAML::NodeType::Scalar: break;
  }
  std::string s = n.Scalar();
  if (s.size() > 60) {
    size_t cut = 57;
    while (cut > 0 && (static_cast<unsigned char>(s[cut]) & 0xC0) == 0x80) --cut;  // not inside a UTF-8 character
    s = s.substr(0, cut) + "...";
  }
  std::string out = "'" + s + "'";
  if (n.Tag() == "!") out += " (a quoted string)";
  return out;
}

[[noreturn]] void wrong_type(const YAML::Node& n, const Where& w, const std::string& key, const std::string& expected) {
  fail(w.file + ": '" + w.key(key) + "': expected " + expected + ", got " + describe(n) + line_of(n));
}

// A plain (unquoted) scalar's text: numbers and bools must not be quoted,
// since YAML reads "1.5" as a string. Nodes built in code have no tag.
bool plain_scalar(const YAML::Node& n, std::string& text) {
  if (!n.IsScalar() || n.Tag() == "!") return false;
  text = n.Scalar();
  return true;
}

// Decimal number with an optional sign (from_chars takes '-' only; "+-1" is
// refused); the whole text must be consumed.
template <class T, class... Format>
bool parse_number(const std::string& text, T& out, Format... format) {
  const size_t start = !text.empty() && text[0] == '+' ? 1 : 0;
  if (start == text.size()) return false;
  if (start == 1 && text[1] == '-') return false;  // "+-1"
  const char* end = text.data() + text.size();
  auto [ptr, ec] = std::from_chars(text.data() + start, end, out, format...);
  return ec == std::errc() && ptr == end;
}

// Decimal integer with optional sign.
bool parse_int64(const std::string& text, int64_t& out) { return parse_number(text, out); }

// Finite decimal number; YAML's .nan/.inf and C's nan/inf are refused.
bool parse_double(const std::string& text, double& out) {
  return parse_number(text, out, std::chars_format::general) && std::isfinite(out);
}

// Optimal string alignment distance (edits, with a swap of neighbours as one
// edit) for the "did you mean" hint on unknown keys.
size_t edit_distance(const std::string& a, const std::string& b) {
  const size_t n = a.size(), m = b.size();
  std::vector<std::vector<size_t>> d(n + 1, std::vector<size_t>(m + 1));
  for (size_t i = 0; i <= n; ++i) d[i][0] = i;
  for (size_t j = 0; j <= m; ++j) d[0][j] = j;
  for (size_t i = 1; i <= n; ++i) {
    for (size_t j = 1; j <= m; ++j) {
      const size_t cost = a[i - 1] == b[j - 1] ? 0 : 1;
      d[i][j] = std::min({d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + cost});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1])
        d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
    }
  }
  return d[n][m];
}

template <class T>
void read_list(const YAML::Node& n, std::vector<T>& out, const Where& w, const std::string& key) {
  if (!n.IsSequence()) wrong_type(n, w, key, "a list");
  std::vector<T> values;
  values.reserve(n.size());
  for (size_t i = 0; i < n.size(); ++i) {
    T v{};
    read_value(n[i], v, w, key + "[" + std::to_string(i) + "]");
    values.push_back(v);
  }
  out = std::move(values);
}

// A copy of a parsed override value with no source marks, so errors about it
// do not point at "line 1" of a file it never was in. Keeps the plain/quoted tag.
YAML::Node unmarked_copy(const YAML::Node& n) {
  switch (n.Type()) {
    case YAML::NodeType::Scalar: {
      YAML::Node s(n.Scalar());
      s.SetTag(n.Tag());
      return s;
    }
    case YAML::NodeType::Sequence: {
      YAML::Node s(YAML::NodeType::Sequence);
      for (const auto& item : n) s.push_back(unmarked_copy(item));
      return s;
    }
    case YAML::NodeType::Map: {
      YAML::Node m(YAML::NodeType::Map);
      for (const auto& kv : n) m[unmarked_copy(kv.first)] = unmarked_copy(kv.second);
      return m;
    }
    default: return YAML::Node(YAML::NodeType::Null);
  }
}

// Sets parent[key] = value as a new entry. Assigning through operator= would
// write into the existing node, which a YAML alias may share with other keys.
// The key keeps its node (and so its line) when it was there.
void replace_entry(YAML::Node& parent, const std::string& key, const YAML::Node& value) {
  YAML::Node key_node;  // (a default Node counts as defined: `found` says whether it was set)
  bool found = false;
  for (const auto& kv : parent)
    if (kv.first.IsScalar() && kv.first.Scalar() == key) {
      key_node = kv.first;
      found = true;
      break;
    }
  parent.remove(key);
  if (found) parent.force_insert(key_node, value);
  else parent[key] = value;
}

void apply_override(YAML::Node& root, const std::string& ov, const std::string& label) {
  const std::string what = label + ": override '" + ov + "'";
  const size_t eq = ov.find('=');
  if (eq == std::string::npos) fail(what + ": expected key.path=value");
  const std::string key = ov.substr(0, eq);
  if (key.empty()) fail(what + ": empty key before '='");
  std::vector<std::string> parts;
  std::stringstream ss(key);
  for (std::string part; std::getline(ss, part, '.');) parts.push_back(part);
  if (key.back() == '.') parts.push_back("");
  for (const auto& p : parts)
    if (p.empty()) fail(what + ": empty name in key path '" + key + "'");

  YAML::Node value;
  try {
    value = unmarked_copy(YAML::Load(ov.substr(eq + 1)));
  } catch (const YAML::Exception& e) {
    fail(what + ": value is not valid YAML: " + e.msg);
  }

  if (!root.IsDefined() || root.IsNull()) root = YAML::Node(YAML::NodeType::Map);
  if (!root.IsMap()) fail(what + ": the top level of the config is not a map of keys");
  YAML::Node cur = root;  // a handle; reset() moves it, operator= would write through it
  std::string path;
  for (size_t i = 0; i + 1 < parts.size(); ++i) {
    path += (i ? "." : "") + parts[i];
    const YAML::Node& view = cur;  // const lookup never inserts
    YAML::Node child = view[parts[i]];
    if (!child || child.IsNull()) {
      replace_entry(cur, parts[i], YAML::Node(YAML::NodeType::Map));
    } else if (child.IsMap()) {
      replace_entry(cur, parts[i], copy_tree(child));  // unshare before writing into it
    } else {
      fail(what + ": '" + path + "' is " + describe(child) + line_of(child) + ", not a section of keys");
    }
    cur.reset(cur[parts[i]]);
  }
  replace_entry(cur, parts.back(), value);
}

// std::to_chars without a format is the shortest text that parses back to
// the same value, and independent of the C locale. Callers never pass NaN/inf
// (the reader refuses them), but they would print as YAML's .nan/.inf.
template <class F>
std::string shortest_text(F x) {
  if (std::isnan(x)) return ".nan";
  if (std::isinf(x)) return x > 0 ? ".inf" : "-.inf";
  char buf[64];
  auto [end, ec] = std::to_chars(buf, buf + sizeof(buf), x);
  return std::string(buf, ec == std::errc() ? end : buf);
}

}  // namespace

// ---- numbers as text ------------------------------------------------------

std::string number_to_yaml(double x) { return shortest_text(x); }
std::string number_to_yaml(float x) { return shortest_text(x); }

// ---- checks ----------------------------------------------------------------

Check range(double lo, double hi) {
  Check c;
  c.number = [lo, hi](double x) {
    return (x >= lo && x <= hi) ? std::string() : "a number in [" + number_to_yaml(lo) + ", " + number_to_yaml(hi) + "]";
  };
  return c;
}

Check positive() {
  Check c;
  c.number = [](double x) { return x > 0 ? std::string() : std::string("a number > 0"); };
  return c;
}

Check non_negative() {
  Check c;
  c.number = [](double x) { return x >= 0 ? std::string() : std::string("a number >= 0"); };
  return c;
}

Check one_of(std::vector<std::string> choices) {
  Check c;
  c.text = [choices = std::move(choices)](const std::string& s) {
    if (std::find(choices.begin(), choices.end(), s) != choices.end()) return std::string();
    std::string list;
    for (const auto& choice : choices) list += (list.empty() ? "" : ", ") + choice;
    return "one of {" + list + "}";
  };
  return c;
}

void apply_check(const Check& c, double value, const Where& w, const std::string& key) {
  if (c.text) fail(w.file + ": '" + w.key(key) + "': a text check (one_of) is attached to a number field");
  if (!c.number) return;
  const std::string expected = c.number(value);
  if (!expected.empty())
    fail(w.file + ": '" + w.key(key) + "': expected " + expected + ", got '" + number_to_yaml(value) + "'");
}

void apply_check(const Check& c, const std::string& value, const Where& w, const std::string& key) {
  if (c.number) fail(w.file + ": '" + w.key(key) + "': a number check is attached to a text field");
  if (!c.text) return;
  const std::string expected = c.text(value);
  if (!expected.empty()) fail(w.file + ": '" + w.key(key) + "': expected " + expected + ", got '" + value + "'");
}

void apply_check(const Check& c, bool value, const Where& w, const std::string& key) {
  (void)value;
  if (c.number || c.text) fail(w.file + ": '" + w.key(key) + "': a check is attached to a true/false field");
}

// ---- scalar conversions ----------------------------------------------------

void read_value(const YAML::Node& n, bool& out, const Where& w, const std::string& key) {
  std::string t;
  if (!plain_scalar(n, t)) wrong_type(n, w, key, "true or false");
  // YAML 1.2 core schema only: yes/no/on/off/1/0 are refused as ambiguous.
  if (t == "true" || t == "True" || t == "TRUE") {
    out = true;
  } else if (t == "false" || t == "False" || t == "FALSE") {
    out = false;
  } else {
    wrong_type(n, w, key, "true or false");
  }
}

void read_value(const YAML::Node& n, int64_t& out, const Where& w, const std::string& key) {
  std::string t;
  if (!plain_scalar(n, t) || !parse_int64(t, out)) wrong_type(n, w, key, "an integer");
}

void read_value(const YAML::Node& n, int& out, const Where& w, const std::string& key) {
  int64_t v = 0;
  std::string t;
  if (!plain_scalar(n, t) || !parse_int64(t, v)) wrong_type(n, w, key, "an integer");
  if (v < std::numeric_limits<int>::min() || v > std::numeric_limits<int>::max())
    wrong_type(n, w, key, "an integer in [-2147483648, 2147483647]");
  out = static_cast<int>(v);
}

void read_value(const YAML::Node& n, double& out, const Where& w, const std::string& key) {
  std::string t;
  if (!plain_scalar(n, t) || !parse_double(t, out)) wrong_type(n, w, key, "a finite number");
}

void read_value(const YAML::Node& n, float& out, const Where& w, const std::string& key) {
  double v = 0;
  read_value(n, v, w, key);
  if (std::abs(v) > double(std::numeric_limits<float>::max())) wrong_type(n, w, key, "a number within float range");
  out = static_cast<float>(v);
}

void read_value(const YAML::Node& n, std::string& out, const Where& w, const std::string& key) {
  if (!n.IsScalar()) wrong_type(n, w, key, "a string (write '' for an empty one)");
  out = n.Scalar();
}

void read_value(const YAML::Node& n, std::vector<int>& out, const Where& w, const std::string& key) {
  read_list(n, out, w, key);
}
void read_value(const YAML::Node& n, std::vector<int64_t>& out, const Where& w, const std::string& key) {
  read_list(n, out, w, key);
}
void read_value(const YAML::Node& n, std::vector<double>& out, const Where& w, const std::string& key) {
  read_list(n, out, w, key);
}
void read_value(const YAML::Node& n, std::vector<float>& out, const Where& w, const std::string& key) {
  read_list(n, out, w, key);
}
void read_value(const YAML::Node& n, std::vector<std::string>& out, const Where& w, const std::string& key) {
  read_list(n, out, w, key);
}

// ---- Reader ----------------------------------------------------------------

Reader::Reader(YAML::Node node, Where where) : node_(std::move(node)), where_(std::move(where)) {
  if (!node_.IsDefined() || node_.IsNull()) return;  // an empty section keeps its defaults
  const std::string what = where_.path.empty() ? "the top level" : "'" + where_.path + "'";
  if (!node_.IsMap()) {
    fail(where_.file + ": " + what + ": expected a section (a map of keys), got " + describe(node_) + line_of(node_));
  }
  // yaml-cpp accepts duplicate keys silently (it keeps every pair and a
  // lookup returns the first), so a repeated key would hide a value: refuse it.
  std::map<std::string, YAML::Node> first;
  for (const auto& kv : node_) {
    if (!kv.first.IsScalar())
      fail(where_.file + ": " + what + ": keys must be plain names, got " + describe(kv.first) +
           line_of(kv.first));
    auto [it, inserted] = first.emplace(kv.first.Scalar(), kv.first);
    if (!inserted) {
      std::string msg = where_.file + ": duplicate key '" + where_.key(kv.first.Scalar()) + "'" + line_of(kv.first);
      const std::string before = line_of(it->second);
      if (!before.empty()) msg += ", first given" + before;
      fail(msg);
    }
  }
}

YAML::Node Reader::lookup(const char* key) {
  known_.emplace_back(key);
  if (!node_.IsMap()) return YAML::Node(YAML::NodeType::Undefined);
  const YAML::Node& view = node_;  // const lookup: never inserts into the document
  return view[key];
}

void Reader::missing(const char* key, const char* help) const {
  std::string msg = where_.file + ": missing required key '" + where_.key(key) + "'";
  if (help && *help) msg += " (" + std::string(help) + ")";
  fail(msg);
}

void Reader::expect_sequence(const YAML::Node& n, const char* key) const {
  if (!n.IsSequence()) wrong_type(n, where_, key, "a list");
}

void Reader::finish() const {
  if (!node_.IsMap()) return;
  std::string errors;
  for (const auto& kv : node_) {
    const std::string k = kv.first.Scalar();
    if (std::find(known_.begin(), known_.end(), k) != known_.end()) continue;
    std::string msg = where_.file + ": unknown key '" + where_.key(k) + "'" + line_of(kv.first);
    size_t best = 3;
    std::string suggestion;
    for (const auto& candidate : known_) {
      const size_t d = edit_distance(k, candidate);
      if (d < best) best = d, suggestion = candidate;
    }
    if (!suggestion.empty()) msg += ", did you mean '" + where_.key(suggestion) + "'?";
    errors += (errors.empty() ? "" : "\n") + msg;
  }
  if (!errors.empty()) fail(errors);
}

// ---- files, text, overrides ------------------------------------------------

YAML::Node load_yaml_text(const std::string& text, const std::string& label) {
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    std::string where;
    if (!e.mark.is_null())
      where = " at line " + std::to_string(e.mark.line + 1) + ", column " + std::to_string(e.mark.column + 1);
    fail(label + ": YAML syntax error" + where + ": " + e.msg);
  }
  return root;
}

YAML::Node load_yaml_file(const std::string& file) {
  std::error_code ec;
  if (!std::filesystem::exists(file, ec)) fail(file + ": config file not found");
  if (std::filesystem::is_directory(file, ec)) fail(file + ": is a folder, expected a YAML config file");
  std::ifstream in(file, std::ios::binary);
  if (!in) fail(file + ": cannot open config file for reading");
  std::stringstream text;
  text << in.rdbuf();
  if (in.bad()) fail(file + ": error while reading config file");
  return load_yaml_text(text.str(), file);
}

void apply_overrides(YAML::Node& root, const std::vector<std::string>& overrides, const std::string& label) {
  for (const auto& ov : overrides) apply_override(root, ov, label);
}

void save_text(const std::string& file, const std::string& yaml) { write_file_atomic(file, yaml); }

std::string Describer::emit(const YAML::Node& node) {
  YAML::Emitter out;
  out << YAML::Flow << node;
  std::string t = out.good() ? out.c_str() : "?";
  return t.empty() ? "''" : t;
}

std::string Describer::markdown() const {
  std::string md = "| key | default | meaning |\n|---|---|---|\n";
  auto cell = [](std::string t) {  // a '|' would end the table cell
    for (size_t i = t.find('|'); i != std::string::npos; i = t.find('|', i + 2)) t.replace(i, 1, "\\|");
    return t;
  };
  for (const auto& r : rows) md += "| `" + r.key + "` | `" + cell(r.value) + "` | " + cell(r.help) + " |\n";
  return md;
}

void rethrow_checked(const Where& where, const std::string& message) {
  fail(where.file + (where.path.empty() ? "" : ": '" + where.path + "'") + ": " + message);
}

YAML::Node merge(const YAML::Node& base, const YAML::Node& overlay) {
  if (!overlay.IsDefined() || overlay.IsNull()) return copy_tree(base);
  if (!base.IsMap() || !overlay.IsMap()) return copy_tree(overlay);
  YAML::Node out = copy_tree(base);
  std::vector<std::string> from_overlay;
  for (const auto& kv : overlay) {
    const std::string key = kv.first.Scalar();
    // A key the overlay gives twice stays twice, for the reader to refuse with both lines.
    if (std::find(from_overlay.begin(), from_overlay.end(), key) != from_overlay.end()) {
      out.force_insert(kv.first, copy_tree(kv.second));
      continue;
    }
    from_overlay.push_back(key);
    const YAML::Node& view = out;  // const lookup never inserts
    YAML::Node mine = view[key];
    YAML::Node merged = mine ? merge(mine, kv.second) : copy_tree(kv.second);
    out.remove(key);
    out.force_insert(kv.first, merged);  // the overlay's key node: its line
  }
  return out;
}

}  // namespace flat::config
