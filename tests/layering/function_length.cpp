#include "layering/function_length.h"

#include <algorithm>
#include <cctype>
#include <stdexcept>

#include "layering/source_files.h"

namespace fs = std::filesystem;

namespace flat::layering {
namespace {

bool is_ident(char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_'; }

// Blanks t[from, to) except newlines.
void blank(std::string& t, size_t from, size_t to) {
  for (size_t k = from; k < to && k < t.size(); ++k)
    if (t[k] != '\n') t[k] = ' ';
}

// Index just past the literal opening at i (a '"' or '\''), escapes honoured;
// a literal never spans a line (an unterminated one ends there).
size_t end_of_quoted(const std::string& t, size_t i) {
  const char q = t[i];
  size_t k = i + 1;
  while (k < t.size() && t[k] != q && t[k] != '\n') k += (t[k] == '\\') ? 2 : 1;
  return std::min(t.size(), k + 1);
}

// Index just past a raw string R"delim( ... )delim" whose '"' is at i.
size_t end_of_raw(const std::string& t, size_t i) {
  const size_t open = t.find('(', i);
  if (open == std::string::npos) return t.size();
  const std::string close = ")" + t.substr(i + 1, open - i - 1) + "\"";
  const size_t end = t.find(close, open);
  return end == std::string::npos ? t.size() : end + close.size();
}

// A preprocessor line starts with '#' after blanks; it runs on over
// backslash-newlines.
size_t end_of_directive(const std::string& t, size_t i) {
  size_t k = i;
  while (k < t.size()) {
    if (t[k] == '\n' && (k == 0 || t[k - 1] != '\\')) return k;
    ++k;
  }
  return k;
}

enum class Block { Scope, Function, MemberInit, Skip };

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r\n");
  if (b == std::string::npos) return "";
  return s.substr(b, s.find_last_not_of(" \t\r\n") - b + 1);
}

bool starts_with_word(const std::string& s, const std::string& w) {
  return s.compare(0, w.size(), w) == 0 && (s.size() == w.size() || !is_ident(s[w.size()]));
}

// The head without what cannot name the block: `template <...>` prefixes,
// access labels, [[attributes]].
std::string strip_prefixes(std::string h) {
  for (bool again = true; again;) {
    again = false;
    h = trim(h);
    if (starts_with_word(h, "template")) {
      const auto lt = h.find('<');
      if (lt == std::string::npos) break;
      int depth = 0;
      size_t k = lt;
      for (; k < h.size(); ++k) {
        if (h[k] == '<') ++depth;
        if (h[k] == '>' && --depth == 0) break;
      }
      h = h.substr(std::min(h.size(), k + 1));
      again = true;
    }
    for (const char* label : {"public", "private", "protected"}) {
      if (!starts_with_word(h, label)) continue;
      const auto rest = trim(h.substr(std::string(label).size()));
      if (!rest.empty() && rest[0] == ':' && (rest.size() < 2 || rest[1] != ':')) {
        h = rest.substr(1);
        again = true;
      }
    }
    if (h.rfind("[[", 0) == 0) {
      const auto end = h.find("]]");
      if (end == std::string::npos) break;
      h = h.substr(end + 2);
      again = true;
    }
  }
  return h;
}

bool has_word(const std::string& s, const std::string& w) {
  for (size_t p = s.find(w); p != std::string::npos; p = s.find(w, p + 1))
    if ((p == 0 || !is_ident(s[p - 1])) && (p + w.size() >= s.size() || !is_ident(s[p + w.size()]))) return true;
  return false;
}

// Position of the first '=' outside parentheses that is an assignment (not
// ==, <=, >=, !=), or npos; a head naming `operator` has none.
size_t top_level_assign(const std::string& h) {
  if (has_word(h, "operator")) return std::string::npos;
  int paren = 0;
  for (size_t k = 0; k < h.size(); ++k) {
    if (h[k] == '(') ++paren;
    if (h[k] == ')') --paren;
    if (h[k] != '=' || paren != 0) continue;
    const char before = k ? h[k - 1] : ' ';
    const char after = k + 1 < h.size() ? h[k + 1] : ' ';
    if (after == '=' || before == '=' || before == '<' || before == '>' || before == '!') continue;
    return k;
  }
  return std::string::npos;
}

// After a parameter list's ')', a lone ':' starts a constructor's member
// initialisers; a '{' right after a name there (`a_{x}`) is one of them.
bool in_member_initialisers(const std::string& h) {
  int paren = 0;
  bool closed = false;
  for (size_t k = 0; k < h.size(); ++k) {
    if (h[k] == '(') ++paren;
    if (h[k] == ')' && --paren == 0) closed = true;
    if (h[k] != ':' || paren != 0 || !closed) continue;
    const bool double_colon = (k + 1 < h.size() && h[k + 1] == ':') || (k > 0 && h[k - 1] == ':');
    if (double_colon) continue;
    const auto last = h.find_last_not_of(" \t\r\n");
    return last != std::string::npos && (is_ident(h[last]) || h[last] == '>');
  }
  return false;
}

Block classify(const std::string& head) {
  const std::string h = strip_prefixes(head);
  const bool paren = h.find('(') != std::string::npos;
  if (starts_with_word(h, "namespace") || starts_with_word(h, "inline")) {
    if (has_word(h, "namespace") && !paren) return Block::Scope;
  }
  if (starts_with_word(h, "extern") && !paren) return Block::Scope;  // extern "C" { (the string is blanked)
  if (starts_with_word(h, "enum")) return Block::Skip;
  const bool class_key = starts_with_word(h, "class") || starts_with_word(h, "struct") ||
                         starts_with_word(h, "union") || starts_with_word(h, "typedef");
  if (class_key && !paren) return Block::Scope;
  if (in_member_initialisers(h)) return Block::MemberInit;
  const auto eq = top_level_assign(h);
  if (eq != std::string::npos) return h.find('(', eq) != std::string::npos ? Block::Function : Block::Skip;
  if (paren) return Block::Function;
  if (has_word(h, "class") || has_word(h, "struct") || has_word(h, "union")) return Block::Scope;
  return Block::Skip;
}

// The name a function's head gives: the (qualified) identifier before its
// parameter list, or for a lambda the variable it is assigned to.
std::string function_name(const std::string& head) {
  const std::string h = strip_prefixes(head);
  const auto eq = top_level_assign(h);
  if (eq != std::string::npos) {
    const std::string lhs = trim(h.substr(0, eq));
    size_t b = lhs.size();
    while (b > 0 && is_ident(lhs[b - 1])) --b;
    return lhs.substr(b) + " (lambda)";
  }
  const auto op = h.find("operator");
  if (op != std::string::npos) {
    const auto paren = h.find('(', h.compare(op + 8, 2, "()") == 0 ? op + 10 : op);
    size_t b = op;
    while (b > 0 && (is_ident(h[b - 1]) || h[b - 1] == ':')) --b;
    return trim(h.substr(b, paren - b));
  }
  const auto paren = h.find('(');
  std::string pre = trim(h.substr(0, paren));
  size_t b = pre.size();
  while (b > 0) {
    const char c = pre[b - 1];
    if (is_ident(c) || c == ':' || c == '~') {
      --b;
    } else if (c == '>') {  // Class<T>::member
      int depth = 0;
      while (b > 0) {
        if (pre[b - 1] == '>') ++depth;
        if (pre[b - 1] == '<' && --depth == 0) break;
        --b;
      }
      if (b > 0) --b;
    } else {
      break;
    }
  }
  return pre.substr(b);
}

// Index of the '}' matching the '{' at i, or npos.
size_t matching_brace(const std::string& t, size_t i) {
  int depth = 0;
  for (size_t k = i; k < t.size(); ++k) {
    if (t[k] == '{') ++depth;
    if (t[k] == '}' && --depth == 0) return k;
  }
  return std::string::npos;
}

}  // namespace

std::string blank_non_code(const std::string& text) {
  std::string t = text;
  bool line_start = true;  // only blanks since the last newline
  for (size_t i = 0; i < t.size();) {
    const char c = t[i];
    const char next = i + 1 < t.size() ? t[i + 1] : '\0';
    size_t end = i;
    if (c == '/' && next == '/') {
      end = t.find('\n', i);
      if (end == std::string::npos) end = t.size();
    } else if (c == '/' && next == '*') {
      end = t.find("*/", i + 2);
      end = end == std::string::npos ? t.size() : end + 2;
    } else if (c == '#' && line_start) {
      end = end_of_directive(t, i);
    } else if (c == 'R' && next == '"' && (i == 0 || !is_ident(t[i - 1]) || std::string("8LuU").find(t[i - 1]) != std::string::npos)) {
      end = end_of_raw(t, i + 1);
    } else if (c == '"') {
      end = end_of_quoted(t, i);
    } else if (c == '\'' && !(i > 0 && std::isdigit(static_cast<unsigned char>(t[i - 1])))) {  // 1'000 is a number
      end = end_of_quoted(t, i);
    }
    if (end > i) {
      blank(t, i, end);
      i = end;
      continue;
    }
    if (c == '\n') line_start = true;
    else if (c != ' ' && c != '\t' && c != '\r') line_start = false;
    ++i;
  }
  return t;
}

std::vector<FunctionSpan> function_spans(const std::string& text, const std::string& file) {
  const std::string t = blank_non_code(text);
  std::vector<size_t> line_starts{0};
  for (size_t k = 0; k < t.size(); ++k)
    if (t[k] == '\n') line_starts.push_back(k + 1);
  const auto line_of = [&](size_t pos) {
    return int(std::upper_bound(line_starts.begin(), line_starts.end(), pos) - line_starts.begin());
  };
  const auto close_of = [&](size_t open) {
    const size_t close = matching_brace(t, open);
    if (close == std::string::npos)
      throw std::runtime_error(file + ":" + std::to_string(line_of(open)) + ": this '{' is never closed");
    return close;
  };

  std::vector<FunctionSpan> out;
  size_t head_start = 0;
  int paren = 0;   // '(' depth in the current head
  int scopes = 0;  // namespaces / classes open
  for (size_t i = 0; i < t.size(); ++i) {
    const char c = t[i];
    if (c == '(') ++paren;
    if (c == ')') --paren;
    if (c == ';' && paren <= 0) {
      head_start = i + 1;
      paren = 0;
    }
    if (c == '}') {
      if (--scopes < 0) throw std::runtime_error(file + ":" + std::to_string(line_of(i)) + ": a '}' closes nothing");
      head_start = i + 1;
      paren = 0;
    }
    if (c != '{') continue;
    if (paren > 0) {  // a brace in a parameter list: `void f(Opts o = {})`
      i = close_of(i);
      continue;
    }
    const std::string head = t.substr(head_start, i - head_start);
    const Block kind = classify(head);
    if (kind == Block::Scope) {
      ++scopes;
      head_start = i + 1;
      continue;
    }
    const size_t close = close_of(i);
    if (kind == Block::Function) out.push_back({file, function_name(head), line_of(i), line_of(close)});
    i = close;
    if (kind != Block::MemberInit) {
      head_start = close + 1;
      paren = 0;
    }
  }
  return out;
}

std::vector<FunctionSpan> scan_folders(const fs::path& root, const std::vector<std::string>& folders) {
  std::vector<FunctionSpan> out;
  for (const auto& folder : folders) {
    const fs::path dir = root / folder;
    if (!fs::is_directory(dir)) throw std::runtime_error("no folder " + dir.string());
    for (const auto& f : code_files(dir)) {
      const auto spans = function_spans(read_text(f), f.lexically_relative(root).generic_string());
      out.insert(out.end(), spans.begin(), spans.end());
    }
  }
  return out;
}

std::string to_string(const FunctionSpan& f, int limit) {
  return f.file + ":" + std::to_string(f.open_line) + ": " + f.name + " is " + std::to_string(f.lines()) +
         " lines (limit " + std::to_string(limit) + ")";
}

}  // namespace flat::layering
