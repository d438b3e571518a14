// The commands that README.md and docs/*.md show, as the docs test checks
// them against the tools' --help (issue #45): extraction from Markdown (fenced
// code blocks and inline code spans) and a shell-like split into commands,
// and the flags a tool's --help lists. Standard library only.
#pragma once
#include <algorithm>
#include <cctype>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace flat::test::docs {

// One invocation of one of our tools, as written in a doc.
struct DocCommand {
  int line = 0;                    // 1-based line where it starts
  std::string tool;                // e.g. flat_bench
  std::vector<std::string> args;   // the words after the tool, quotes removed
  std::string text;                // the command line as written (joined), for messages
  // A fenced line of flags alone ("  --mode streaming|full  --device cpu|cuda")
  // under a command: the flags of that tool, of whichever subcommand.
  bool flags_only = false;
};

// A word of a shell line: its text with quotes removed, and whether any of
// it was quoted (a quoted word holding spaces may itself be a command line,
// as in `bash -c '... flat_train --config x'`).
struct Word {
  std::string text;
  bool quoted = false;
};

// Splits one logical shell line into simple commands: words separated by
// blanks, commands by ; & | ( ) and newlines; a # at the start of a word
// begins a comment. Quotes group; backslash escapes the next character.
inline std::vector<std::vector<Word>> split_shell(const std::string& line) {
  std::vector<std::vector<Word>> cmds(1);
  Word cur;
  bool in_word = false;
  auto end_word = [&] {
    if (in_word) cmds.back().push_back(cur);
    cur = Word{};
    in_word = false;
  };
  auto end_cmd = [&] {
    end_word();
    if (!cmds.back().empty()) cmds.emplace_back();
  };
  for (size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (c == '\'' || c == '"') {
      const size_t close = line.find(c, i + 1);
      const size_t stop = close == std::string::npos ? line.size() : close;
      cur.text += line.substr(i + 1, stop - i - 1);
      cur.quoted = true;
      in_word = true;
      i = stop;
    } else if (c == '\\' && i + 1 < line.size()) {
      cur.text += line[++i];
      in_word = true;
    } else if (c == '#' && !in_word) {
      break;  // a comment runs to the end of the line
    } else if (c == ';' || c == '&' || c == '|' || c == '(' || c == ')' || c == '\n') {
      end_cmd();
    } else if (std::isspace(static_cast<unsigned char>(c))) {
      end_word();
    } else {
      cur.text += c;
      in_word = true;
    }
  }
  end_cmd();
  cmds.pop_back();  // always an empty one at the end
  return cmds;
}

inline std::string basename_of(const std::string& word) {
  const size_t slash = word.rfind('/');
  return slash == std::string::npos ? word : word.substr(slash + 1);
}

// The tool invocations in one logical line: in each simple command, from the
// first word naming one of `tools` (any directory before it: build/flat_x,
// $B/flat_x, ./flat_x; env assignments and launchers such as torchrun before
// it) to the end of that command. A quoted word that itself holds a tool and
// a blank is read as a command line of its own.
inline void commands_in_line(const std::string& line, int line_no, const std::set<std::string>& tools,
                             std::vector<DocCommand>& out) {
  for (const auto& words : split_shell(line)) {
    for (size_t i = 0; i < words.size(); ++i) {
      const Word& w = words[i];
      if (w.quoted && w.text.find(' ') != std::string::npos) {
        commands_in_line(w.text, line_no, tools, out);
        continue;
      }
      if (!tools.count(basename_of(w.text))) continue;
      DocCommand c;
      c.line = line_no;
      c.tool = basename_of(w.text);
      std::string text = c.tool;
      for (size_t j = i + 1; j < words.size(); ++j) {
        c.args.push_back(words[j].text);
        text += " " + words[j].text;
      }
      c.text = text;
      out.push_back(c);
      break;
    }
  }
}

// Languages of fenced blocks that hold no shell commands.
inline bool data_language(const std::string& lang) {
  static const std::set<std::string> data = {"json", "yaml", "yml", "toml", "python", "py", "cpp", "c++",
                                             "cmake", "html", "js", "javascript", "csv"};
  return data.count(lang) > 0;
}

// Every tool invocation of a Markdown text: the lines of fenced code blocks
// (``` or ~~~; blocks tagged json, yaml, ... skipped; a line ending in a
// backslash continues on the next), and the inline code spans of the other
// paragraphs (a span may cross a line break; \| in a table cell is a |).
inline std::vector<DocCommand> extract_commands(const std::string& markdown, const std::set<std::string>& tools) {
  std::vector<std::string> lines;
  {
    std::istringstream in(markdown);
    std::string l;
    while (std::getline(in, l)) lines.push_back(l);
  }
  std::vector<DocCommand> out;
  std::string para;  // the current paragraph outside fences, lines joined by '\n'
  int para_line = 0;
  auto flush_paragraph = [&] {
    size_t i = 0;
    while (i < para.size()) {
      if (para[i] != '`') {
        ++i;
        continue;
      }
      size_t n = 0;
      while (i + n < para.size() && para[i + n] == '`') ++n;
      const std::string fence(n, '`');
      size_t close = para.find(fence, i + n);
      // The closing run must be exactly n backticks long.
      while (close != std::string::npos && close + n < para.size() && para[close + n] == '`')
        close = para.find(fence, close + n + 1);
      if (close == std::string::npos) break;
      std::string span = para.substr(i + n, close - i - n);
      const int line_no = para_line + static_cast<int>(std::count(para.begin(), para.begin() + i, '\n'));
      std::replace(span.begin(), span.end(), '\n', ' ');
      for (size_t p = 0; (p = span.find("\\|", p)) != std::string::npos;) span.replace(p, 2, "|");
      commands_in_line(span, line_no, tools, out);
      i = close + n;
    }
    para.clear();
  };
  // A logical line of a fenced block; one that starts with a flag lists flags
  // of the block's last tool (no shell command starts with --).
  std::string fence_tool;
  auto fenced_line = [&](const std::string& line, int line_no) {
    const size_t first = line.find_first_not_of(" \t");
    if (first != std::string::npos && line.compare(first, 2, "--") == 0 && !fence_tool.empty()) {
      const auto cmds = split_shell(line);
      DocCommand c;
      c.line = line_no;
      c.tool = fence_tool;
      c.flags_only = true;
      c.text = fence_tool + " ...";
      for (const auto& cmd : cmds)  // a | here separates values (fp32|bf16), not commands
        for (const auto& w : cmd) {
          c.args.push_back(w.text);
          c.text += " " + w.text;
        }
      out.push_back(c);
      return;
    }
    const size_t before = out.size();
    commands_in_line(line, line_no, tools, out);
    if (out.size() > before) fence_tool = out.back().tool;
  };
  bool in_fence = false, skip_fence = false;
  std::string fence_marker;
  std::string pending;  // a fenced line continued with a backslash
  int pending_line = 0;
  for (size_t k = 0; k < lines.size(); ++k) {
    const std::string& l = lines[k];
    const int line_no = static_cast<int>(k) + 1;
    const size_t lead = l.find_first_not_of(' ');
    const std::string body = lead == std::string::npos ? "" : l.substr(lead);
    const bool is_marker = body.rfind("```", 0) == 0 || body.rfind("~~~", 0) == 0;
    if (!in_fence && is_marker) {
      flush_paragraph();
      in_fence = true;
      fence_tool.clear();
      fence_marker = body.substr(0, 3);
      const size_t info = body.find_first_not_of(fence_marker[0]);
      std::string lang = info == std::string::npos ? "" : body.substr(info);
      lang = lang.substr(0, lang.find_first_of(" {"));
      std::transform(lang.begin(), lang.end(), lang.begin(), [](unsigned char ch) { return std::tolower(ch); });
      skip_fence = data_language(lang);
      continue;
    }
    if (in_fence) {
      if (body.rfind(fence_marker, 0) == 0 && body.find_first_not_of(fence_marker[0]) == std::string::npos) {
        in_fence = false;
        if (!pending.empty()) fenced_line(pending, pending_line);
        pending.clear();
        continue;
      }
      if (skip_fence) continue;
      if (pending.empty()) pending_line = line_no;
      if (!l.empty() && l.back() == '\\') {
        pending += l.substr(0, l.size() - 1) + " ";
        continue;
      }
      pending += l;
      fenced_line(pending, pending_line);
      pending.clear();
      continue;
    }
    if (body.empty()) {
      flush_paragraph();
      continue;
    }
    if (para.empty()) para_line = line_no;
    else para += '\n';
    para += l;
  }
  flush_paragraph();
  return out;
}

// What one --help lists: every option name (long and short spellings), which
// of them take a value, and the subcommands.
struct HelpInfo {
  std::set<std::string> flags;
  std::set<std::string> takes_value;
  std::vector<std::string> subcommands;
};

// Reads CLI11's help layout: option lines start with two blanks and a dash,
// names separated by commas, then an upper-case type (TEXT, INT, ...) when
// the option takes a value; subcommands are listed under "Subcommands:".
inline HelpInfo parse_help(const std::string& help) {
  HelpInfo h;
  std::istringstream in(help);
  std::string l;
  bool in_subcommands = false;
  while (std::getline(in, l)) {
    if (l.rfind("Subcommands:", 0) == 0) {
      in_subcommands = true;
      continue;
    }
    if (l.empty() || !std::isspace(static_cast<unsigned char>(l[0]))) {
      in_subcommands = false;
      continue;
    }
    if (in_subcommands) {
      if (l.rfind("  ", 0) == 0 && l.size() > 2 && std::isalnum(static_cast<unsigned char>(l[2])))
        h.subcommands.push_back(l.substr(2, l.find(' ', 2) - 2));
      continue;
    }
    if (l.rfind("  -", 0) != 0) continue;
    std::istringstream words(l.substr(2));
    std::string names, type;
    words >> names >> type;
    const bool value = !type.empty() && std::isupper(static_cast<unsigned char>(type[0])) &&
                       type.size() >= 2 && std::isupper(static_cast<unsigned char>(type[1]));
    std::istringstream split(names);
    std::string name;
    while (std::getline(split, name, ',')) {
      if (name.empty() || name[0] != '-') continue;
      h.flags.insert(name);
      if (value) h.takes_value.insert(name);
    }
  }
  return h;
}

// The long flag a word spells (--name of --name=value), or "" when the word
// is none: a value, a placeholder (...), a bare --.
inline std::string flag_of(std::string word) {
  while (!word.empty() && (word.front() == '[' || word.front() == '{')) word.erase(0, 1);
  if (word.size() < 3 || word.compare(0, 2, "--") != 0 || !std::isalpha(static_cast<unsigned char>(word[2]))) return "";
  word = word.substr(0, word.find('='));
  while (!word.empty() && std::string("]},.:").find(word.back()) != std::string::npos) word.pop_back();
  return word;
}

// The long flags a word spells: one, or alternatives written --a/--b.
inline std::vector<std::string> flags_of(const std::string& word) {
  std::vector<std::string> flags;
  if (word.find("/--") == std::string::npos) {
    if (auto f = flag_of(word); !f.empty()) flags.push_back(f);
    return flags;
  }
  std::istringstream parts(word);
  std::string part;
  while (std::getline(parts, part, '/'))
    if (auto f = flag_of(part); !f.empty()) flags.push_back(f);
  return flags;
}

}  // namespace flat::test::docs
