// How long each function is, read from the text of C++ sources: the check
// behind "no driver function over 80 lines" (docs/development.md). Plain C++
// (no torch, no compiler): a brace-matching scan.
//
// What it sees: comments, string and character literals (raw strings too) and
// preprocessor lines are blanked first, so braces inside them do not count.
// Then, at namespace, class or extern "C" scope, a '{' opens
// - a scope again, after `namespace`, `extern "C"`, or `class`/`struct`/`union`
//   with no '(' in its head;
// - a function body when its head (the text since the last ';', '{' or '}' at
//   that scope) has a '(': free and member functions, constructors (their
//   member initialisers `a_{x}` are read as part of the head), operators, and
//   lambdas assigned at namespace scope (`auto f = [](...) {`);
// - anything else (an initialiser `= {...}`, an enum) is skipped whole.
// A function's length is its body: the line of its '{' to the line of its
// '}', both counted. A lambda or local class inside a function is part of it.
// Limits (it is not a parser): a macro that expands to braces, or a '{' or
// '}' made by the preprocessor (#if branches that each open a brace), can
// mislead it; a function-like macro call at namespace scope followed by a
// block (`TEST_CASE(...) {`) is read as a function, which is what we want.
#pragma once
#include <filesystem>
#include <string>
#include <vector>

namespace flat::layering {

struct FunctionSpan {
  std::string file;  // as given, or relative to the root for scan_folders
  std::string name;  // the qualified name before its '(' (a lambda: the variable)
  int open_line = 0;   // the line of its body's '{' (1-based)
  int close_line = 0;  // the line of its body's '}'
  int lines() const { return close_line - open_line + 1; }
};

// The text with comments, literals and preprocessor lines replaced by
// spaces (newlines kept, so line numbers hold).
std::string blank_non_code(const std::string& text);

// Every function body of one source text.
std::vector<FunctionSpan> function_spans(const std::string& text, const std::string& file);

// Every function of the C++/CUDA files under root/<folder> for each folder,
// with file names relative to root.
std::vector<FunctionSpan> scan_folders(const std::filesystem::path& root, const std::vector<std::string>& folders);

// "file:line: name is N lines (limit L)".
std::string to_string(const FunctionSpan& f, int limit);

}  // namespace flat::layering
