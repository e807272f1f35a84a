#include "services/scene/tokenizer.h"

#include <utility>

namespace prism::scene {

const char* token_kind_name(Token::Kind kind) {
  switch (kind) {
    case Token::Kind::kWord: return "word";
    case Token::Kind::kString: return "string";
    case Token::Kind::kOpenBracket: return "'['";
    case Token::Kind::kCloseBracket: return "']'";
    case Token::Kind::kEnd: return "end of file";
  }
  return "token";
}

Tokenizer::Tokenizer(std::string_view text, std::string file)
    : text_(text), file_(std::move(file)), peeked_(Token{}) {}

char Tokenizer::advance() {
  char c = text_[pos_++];
  if (c == '\n') {
    ++line_;
    column_ = 1;
  } else {
    ++column_;
  }
  return c;
}

void Tokenizer::skip_space_and_comments() {
  while (pos_ < text_.size()) {
    char c = text_[pos_];
    if (c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\f' || c == '\v') {
      advance();
    } else if (c == '#') {
      while (pos_ < text_.size() && text_[pos_] != '\n') advance();
    } else {
      break;
    }
  }
}

absl::StatusOr<Token> Tokenizer::peek() {
  if (!has_peeked_) {
    peeked_ = scan();
    has_peeked_ = true;
  }
  return peeked_;
}

absl::StatusOr<Token> Tokenizer::next() {
  if (has_peeked_) {
    has_peeked_ = false;
    return std::move(peeked_);
  }
  return scan();
}

absl::StatusOr<Token> Tokenizer::scan() {
  skip_space_and_comments();
  Token t;
  t.line = line_;
  t.column = column_;
  if (pos_ >= text_.size()) return t;
  SourceLocation where{file_, line_, column_};
  char c = text_[pos_];
  if (c == '[' || c == ']') {
    advance();
    t.kind = c == '[' ? Token::Kind::kOpenBracket : Token::Kind::kCloseBracket;
    t.text = std::string(1, c);
    return t;
  }
  if (c == '"') {
    advance();
    t.kind = Token::Kind::kString;
    while (true) {
      if (pos_ >= text_.size() || text_[pos_] == '\n' || text_[pos_] == '\r')
        return location_error(where, "unterminated string");
      char s = advance();
      if (s == '"') break;
      if (s == '\\') {
        if (pos_ >= text_.size()) return location_error(where, "unterminated string");
        SourceLocation escape_at{file_, line_, column_ - 1};
        char e = advance();
        switch (e) {
          case '"': t.text.push_back('"'); break;
          case '\\': t.text.push_back('\\'); break;
          case 'n': t.text.push_back('\n'); break;
          case 't': t.text.push_back('\t'); break;
          default:
            return location_error(escape_at, std::string("unknown escape '\\") + e + "' in string");
        }
        continue;
      }
      if (static_cast<unsigned char>(s) < 0x20 && s != '\t')
        return location_error(where, "control character in string");
      t.text.push_back(s);
    }
    return t;
  }
  if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f)
    return location_error(where, "unexpected control character");
  t.kind = Token::Kind::kWord;
  while (pos_ < text_.size()) {
    char w = text_[pos_];
    if (w == ' ' || w == '\t' || w == '\n' || w == '\r' || w == '\f' || w == '\v' || w == '"' ||
        w == '[' || w == ']' || w == '#')
      break;
    if (static_cast<unsigned char>(w) < 0x20 || w == 0x7f)
      return location_error({file_, line_, column_}, "unexpected control character");
    t.text.push_back(advance());
  }
  return t;
}

}  // namespace prism::scene
