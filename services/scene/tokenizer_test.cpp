#include "services/scene/tokenizer.h"

#include <gtest/gtest.h>

#include <vector>

namespace prism::scene {
namespace {

std::vector<Token> all_tokens(std::string_view text) {
  Tokenizer t(text, "t.pbrt");
  std::vector<Token> out;
  while (true) {
    absl::StatusOr<Token> tok = t.next();
    EXPECT_TRUE(tok.ok()) << tok.status();
    if (!tok.ok() || tok->kind == Token::Kind::kEnd) break;
    out.push_back(*tok);
  }
  return out;
}

TEST(Tokenizer, WordsStringsBracketsAndPositions) {
  std::vector<Token> t = all_tokens("Shape \"sphere\" # comment\n  \"float radius\" [ 2.5 ]\n");
  ASSERT_EQ(t.size(), 6u);
  EXPECT_EQ(t[0].kind, Token::Kind::kWord);
  EXPECT_EQ(t[0].text, "Shape");
  EXPECT_EQ(t[1].kind, Token::Kind::kString);
  EXPECT_EQ(t[1].text, "sphere");
  EXPECT_EQ(t[1].column, 7);
  EXPECT_EQ(t[2].text, "float radius");
  EXPECT_EQ(t[2].line, 2);
  EXPECT_EQ(t[2].column, 3);
  EXPECT_EQ(t[3].kind, Token::Kind::kOpenBracket);
  EXPECT_EQ(t[4].text, "2.5");
  EXPECT_EQ(t[5].kind, Token::Kind::kCloseBracket);
  EXPECT_EQ(t[5].column, 24);
}

TEST(Tokenizer, EscapesAndBracketsWithoutSpaces) {
  std::vector<Token> t = all_tokens("[1 2]\"a\\\"b\\\\c\"");
  ASSERT_EQ(t.size(), 5u);
  EXPECT_EQ(t[2].text, "2");
  EXPECT_EQ(t[4].text, "a\"b\\c");
}

TEST(Tokenizer, PeekDoesNotConsume) {
  Tokenizer t("A B", "t.pbrt");
  EXPECT_EQ(t.peek()->text, "A");
  EXPECT_EQ(t.next()->text, "A");
  EXPECT_EQ(t.next()->text, "B");
  EXPECT_EQ(t.next()->kind, Token::Kind::kEnd);
  EXPECT_EQ(t.next()->kind, Token::Kind::kEnd);
}

TEST(Tokenizer, Errors) {
  {
    Tokenizer t("WorldBegin \"abc\nShape", "t.pbrt");
    ASSERT_TRUE(t.next().ok());
    EXPECT_EQ(std::string(t.next().status().message()), "t.pbrt:1:12: unterminated string");
  }
  {
    Tokenizer t("\"a\\qb\"", "t.pbrt");
    EXPECT_EQ(std::string(t.next().status().message()), "t.pbrt:1:3: unknown escape '\\q' in string");
  }
  {
    Tokenizer t(std::string_view("A\0B", 3), "t.pbrt");
    EXPECT_EQ(std::string(t.next().status().message()), "t.pbrt:1:2: unexpected control character");
  }
}

}  // namespace
}  // namespace prism::scene
