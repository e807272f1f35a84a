// The lexical layer of the pbrt-v4 scene format: splits a file's text into words (directive
// names, numbers, `true`/`false`), quoted strings and brackets, each with its line and
// column. `#` starts a comment to the end of the line. Strings may not span lines and know
// the escapes \" \\ \n \t. The tokenizer does not own the text; the caller keeps it alive.
#pragma once

#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "services/scene/source_location.h"

namespace prism::scene {

struct Token {
  enum class Kind { kWord, kString, kOpenBracket, kCloseBracket, kEnd };
  Kind kind = Kind::kEnd;
  // Word text, or the string's content with escapes resolved.
  std::string text;
  int line = 0;
  int column = 0;
};

const char* token_kind_name(Token::Kind kind);

class Tokenizer {
 public:
  // `file` is used only in messages and locations.
  Tokenizer(std::string_view text, std::string file);

  // The next token (kEnd at the end, repeatedly). Errors: unterminated string, a control
  // character, a backslash escape pbrt does not know.
  absl::StatusOr<Token> next();
  // The next token without consuming it.
  absl::StatusOr<Token> peek();

  const std::string& file() const { return file_; }
  SourceLocation location(const Token& t) const { return {file_, t.line, t.column}; }

 private:
  absl::StatusOr<Token> scan();
  void skip_space_and_comments();
  char advance();

  std::string_view text_;
  std::string file_;
  size_t pos_ = 0;
  int line_ = 1;
  int column_ = 1;
  bool has_peeked_ = false;
  absl::StatusOr<Token> peeked_;
};

}  // namespace prism::scene
