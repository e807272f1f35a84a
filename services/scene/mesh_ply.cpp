#include "services/scene/mesh_ply.h"

#include <algorithm>
#include <array>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "services/base/atomic_file.h"
#include "services/base/check.h"
#include "services/base/status.h"

namespace prism::scene {
namespace {

enum class Format { kAscii, kBinaryLittleEndian, kBinaryBigEndian };

enum class ScalarType : std::uint8_t {
  kInt8,
  kUint8,
  kInt16,
  kUint16,
  kInt32,
  kUint32,
  kFloat32,
  kFloat64
};

struct TypeName {
  absl::string_view name;
  ScalarType type;
};

constexpr TypeName kTypeNames[] = {
    {"char", ScalarType::kInt8},      {"int8", ScalarType::kInt8},
    {"uchar", ScalarType::kUint8},    {"uint8", ScalarType::kUint8},
    {"short", ScalarType::kInt16},    {"int16", ScalarType::kInt16},
    {"ushort", ScalarType::kUint16},  {"uint16", ScalarType::kUint16},
    {"int", ScalarType::kInt32},      {"int32", ScalarType::kInt32},
    {"uint", ScalarType::kUint32},    {"uint32", ScalarType::kUint32},
    {"float", ScalarType::kFloat32},  {"float32", ScalarType::kFloat32},
    {"double", ScalarType::kFloat64}, {"float64", ScalarType::kFloat64},
};

std::optional<ScalarType> parse_type(absl::string_view name) {
  for (const TypeName& t : kTypeNames) {
    if (t.name == name) return t.type;
  }
  return std::nullopt;
}

// Calls f with a value of the C++ type that stores `type`.
template <typename F>
decltype(auto) with_type(ScalarType type, F&& f) {
  switch (type) {
    case ScalarType::kInt8:
      return f(std::int8_t{});
    case ScalarType::kUint8:
      return f(std::uint8_t{});
    case ScalarType::kInt16:
      return f(std::int16_t{});
    case ScalarType::kUint16:
      return f(std::uint16_t{});
    case ScalarType::kInt32:
      return f(std::int32_t{});
    case ScalarType::kUint32:
      return f(std::uint32_t{});
    case ScalarType::kFloat32:
      return f(float{});
    case ScalarType::kFloat64:
      return f(double{});
  }
  PRISM_CHECK_MSG(false, "unknown PLY scalar type");
}

std::uint64_t type_size(ScalarType type) {
  return with_type(type, [](auto v) -> std::uint64_t { return sizeof(v); });
}

bool is_integer(ScalarType type) {
  return type != ScalarType::kFloat32 && type != ScalarType::kFloat64;
}

// What the reader does with a property's values.
enum class Role : std::uint8_t { kX, kY, kZ, kNx, kNy, kNz, kU, kV, kSkip, kFaceIndices };
constexpr int kVertexRoles = 8;

struct Property {
  std::string name;
  bool is_list = false;
  ScalarType type = ScalarType::kFloat32;      // value type; item type for lists
  ScalarType count_type = ScalarType::kUint8;  // lists only
  Role role = Role::kSkip;
};

struct Element {
  std::string name;
  std::uint64_t count = 0;
  std::size_t line = 0;
  std::vector<Property> properties;
};

struct Header {
  Format format = Format::kAscii;
  std::vector<Element> elements;
  std::size_t body_offset = 0;
  std::size_t body_first_line = 0;
};

absl::Status header_error(absl::string_view name, std::size_t line, absl::string_view message) {
  return absl::InvalidArgumentError(absl::StrCat(name, ":", line, ": ", message));
}

bool parse_u64(absl::string_view token, std::uint64_t* out) {
  auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), *out);
  return ec == std::errc() && end == token.data() + token.size() && !token.empty();
}

// The words of a header line. No keyword takes more than kMaxWords words, so only one more is
// kept to detect excess: a huge header line cannot make the reader allocate.
class HeaderWords {
 public:
  static constexpr std::size_t kMaxWords = 5;

  explicit HeaderWords(absl::string_view line) {
    for (absl::string_view word : absl::StrSplit(line, absl::ByAnyChar(" \t"), absl::SkipEmpty())) {
      if (count_ == words_.size()) break;
      words_[count_++] = word;
    }
  }
  std::size_t size() const { return count_; }
  bool empty() const { return count_ == 0; }
  absl::string_view operator[](std::size_t i) const {
    PRISM_CHECK(i < count_);
    return words_[i];
  }

 private:
  std::array<absl::string_view, kMaxWords + 1> words_;
  std::size_t count_ = 0;
};

absl::StatusOr<Header> parse_header(absl::string_view bytes, absl::string_view name) {
  Header header;
  std::size_t pos = 0;
  std::size_t line_no = 0;
  auto next_line = [&](absl::string_view* line) {
    std::size_t newline = bytes.find('\n', pos);
    if (newline == absl::string_view::npos) return false;
    *line = bytes.substr(pos, newline - pos);
    if (!line->empty() && line->back() == '\r') line->remove_suffix(1);
    pos = newline + 1;
    ++line_no;
    return true;
  };

  absl::string_view line;
  if (!next_line(&line) || line != "ply") {
    return header_error(name, 1, "not a PLY file: the first line must be 'ply'");
  }
  bool have_format = false;
  for (;;) {
    if (!next_line(&line)) {
      return header_error(name, line_no + 1, "the header ends without 'end_header'");
    }
    HeaderWords tokens(line);
    if (tokens.empty()) continue;
    absl::string_view keyword = tokens[0];
    if (keyword == "comment" || keyword == "obj_info") continue;
    if (keyword == "end_header") {
      if (tokens.size() != 1) return header_error(name, line_no, "malformed 'end_header' line");
      break;
    }
    if (keyword == "format") {
      if (have_format) return header_error(name, line_no, "more than one 'format' line");
      if (tokens.size() != 3) {
        return header_error(name, line_no, "expected 'format <ascii|binary_...> 1.0'");
      }
      if (tokens[1] == "ascii") {
        header.format = Format::kAscii;
      } else if (tokens[1] == "binary_little_endian") {
        header.format = Format::kBinaryLittleEndian;
      } else if (tokens[1] == "binary_big_endian") {
        header.format = Format::kBinaryBigEndian;
      } else {
        return header_error(name, line_no, absl::StrCat("unknown PLY format '", tokens[1], "'"));
      }
      if (tokens[2] != "1.0") {
        return header_error(name, line_no,
                            absl::StrCat("unsupported PLY version '", tokens[2], "'"));
      }
      have_format = true;
      continue;
    }
    if (keyword == "element") {
      if (tokens.size() != 3)
        return header_error(name, line_no, "expected 'element <name> <count>'");
      Element element;
      element.name = std::string(tokens[1]);
      element.line = line_no;
      if (!parse_u64(tokens[2], &element.count)) {
        return header_error(name, line_no, absl::StrCat("bad element count '", tokens[2], "'"));
      }
      for (const Element& e : header.elements) {
        if (e.name == element.name) {
          return header_error(name, line_no,
                              absl::StrCat("element '", element.name, "' is declared twice"));
        }
      }
      header.elements.push_back(std::move(element));
      continue;
    }
    if (keyword == "property") {
      if (header.elements.empty()) {
        return header_error(name, line_no, "'property' before any 'element'");
      }
      Property property;
      if (tokens.size() >= 2 && tokens[1] == "list") {
        if (tokens.size() != 5) {
          return header_error(name, line_no,
                              "expected 'property list <count type> <item type> <name>'");
        }
        auto count_type = parse_type(tokens[2]);
        auto item_type = parse_type(tokens[3]);
        if (!count_type || !item_type) {
          return header_error(
              name, line_no,
              absl::StrCat("unknown property type '", count_type ? tokens[3] : tokens[2], "'"));
        }
        if (!is_integer(*count_type)) {
          return header_error(name, line_no, "a list count type must be an integer type");
        }
        property.is_list = true;
        property.count_type = *count_type;
        property.type = *item_type;
        property.name = std::string(tokens[4]);
      } else {
        if (tokens.size() != 3)
          return header_error(name, line_no, "expected 'property <type> <name>'");
        auto type = parse_type(tokens[1]);
        if (!type) {
          return header_error(name, line_no,
                              absl::StrCat("unknown property type '", tokens[1], "'"));
        }
        property.type = *type;
        property.name = std::string(tokens[2]);
      }
      Element& element = header.elements.back();
      for (const Property& p : element.properties) {
        if (p.name == property.name) {
          return header_error(name, line_no,
                              absl::StrCat("property '", property.name, "' of element '",
                                           element.name, "' is declared twice"));
        }
      }
      element.properties.push_back(std::move(property));
      continue;
    }
    return header_error(name, line_no, absl::StrCat("unknown header keyword '", keyword, "'"));
  }
  if (!have_format) return header_error(name, line_no, "the header has no 'format' line");
  header.body_offset = pos;
  header.body_first_line = line_no + 1;
  return header;
}

// Assigns roles to the vertex and face properties; checks the elements a mesh needs.
absl::Status assign_roles(Header& header, absl::string_view name, Element** vertex_out,
                          Element** face_out) {
  Element* vertex = nullptr;
  Element* face = nullptr;
  for (Element& e : header.elements) {
    if (e.name == "vertex") vertex = &e;
    if (e.name == "face") face = &e;
  }
  if (vertex == nullptr) {
    return absl::InvalidArgumentError(
        absl::StrCat(name, ": the header declares no 'vertex' element"));
  }
  auto find_scalar = [&](absl::string_view prop) -> Property* {
    for (Property& p : vertex->properties) {
      if (p.name == prop && !p.is_list) return &p;
    }
    return nullptr;
  };
  Property* x = find_scalar("x");
  Property* y = find_scalar("y");
  Property* z = find_scalar("z");
  if (!x || !y || !z) {
    return header_error(name, vertex->line,
                        "the 'vertex' element needs scalar properties x, y and z");
  }
  if (face == nullptr) {
    return absl::InvalidArgumentError(absl::StrCat(
        name, ": the header declares no 'face' element; only triangle meshes are supported"));
  }
  x->role = Role::kX;
  y->role = Role::kY;
  z->role = Role::kZ;
  Property* nx = find_scalar("nx");
  Property* ny = find_scalar("ny");
  Property* nz = find_scalar("nz");
  if (nx && ny && nz) {
    nx->role = Role::kNx;
    ny->role = Role::kNy;
    nz->role = Role::kNz;
  }
  constexpr std::pair<absl::string_view, absl::string_view> kUvNames[] = {
      {"u", "v"}, {"s", "t"}, {"texture_u", "texture_v"}, {"texture_s", "texture_t"}};
  for (const auto& [u_name, v_name] : kUvNames) {
    Property* u = find_scalar(u_name);
    Property* v = find_scalar(v_name);
    if (u && v) {
      u->role = Role::kU;
      v->role = Role::kV;
      break;
    }
  }

  Property* indices = nullptr;
  for (Property& p : face->properties) {
    if (p.name == "vertex_indices" || p.name == "vertex_index") {
      indices = &p;
      break;
    }
  }
  if (indices == nullptr) {
    return header_error(name, face->line,
                        "the 'face' element has no 'vertex_indices' list property");
  }
  if (!indices->is_list) {
    return header_error(name, face->line,
                        absl::StrCat("face property '", indices->name, "' must be a list"));
  }
  if (!is_integer(indices->type)) {
    return header_error(name, face->line, "face vertex indices must have an integer type");
  }
  indices->role = Role::kFaceIndices;
  *vertex_out = vertex;
  *face_out = face;
  return absl::OkStatus();
}

// Refuses element counts that cannot fit in the bytes after the header, before anything is
// allocated. A binary item needs at least its scalar sizes plus its list counts; an ascii item
// needs at least two characters (digit and separator) per value.
absl::Status check_counts_fit(const Header& header, std::uint64_t body_bytes,
                              absl::string_view name) {
  std::uint64_t remaining = body_bytes;
  bool ascii = header.format == Format::kAscii;
  if (ascii) remaining += 1;  // the last value needs no separator
  for (const Element& e : header.elements) {
    std::uint64_t min_item = 0;
    for (const Property& p : e.properties) {
      min_item += ascii ? 2 : (p.is_list ? type_size(p.count_type) : type_size(p.type));
    }
    if (min_item == 0 || e.count == 0) continue;
    if (e.count > remaining / min_item) {
      return header_error(
          name, e.line,
          absl::StrCat("the header declares ", e.count, " '", e.name, "' items of at least ",
                       min_item, " bytes each, but only ", body_bytes,
                       " bytes follow the header (truncated or corrupt file)"));
    }
    remaining -= e.count * min_item;
  }
  return absl::OkStatus();
}

// Reads binary values with bounds checks. On failure a method returns false and records why;
// the caller adds which item it was reading.
class BinaryReader {
 public:
  BinaryReader(absl::string_view bytes, std::size_t pos, bool big_endian)
      : bytes_(bytes), pos_(pos), swap_(big_endian != (std::endian::native == std::endian::big)) {}

  bool read_number(ScalarType type, double* out) {
    return with_type(type, [&](auto v) { return load<decltype(v)>(out); });
  }

  bool read_integer(ScalarType type, std::int64_t* out) {
    PRISM_CHECK(is_integer(type));
    return with_type(type, [&](auto v) {
      if constexpr (std::is_integral_v<decltype(v)>) {
        return load<decltype(v)>(out);
      } else {
        return false;
      }
    });
  }

  bool skip(ScalarType type, std::uint64_t n) {
    // n comes from a list count of at most 32 bits, so this cannot overflow.
    std::uint64_t size = n * type_size(type);
    if (size > bytes_.size() - pos_) {
      problem_pos_ = pos_;
      problem_ = absl::StrCat("unexpected end of data: a list needs ", size, " bytes, ",
                              bytes_.size() - pos_, " remain");
      return false;
    }
    pos_ += size;
    return true;
  }

  absl::Status finish(absl::string_view name) const {
    if (pos_ != bytes_.size()) {
      return absl::InvalidArgumentError(absl::StrCat(
          name, ": byte offset ", pos_, ": ", bytes_.size() - pos_,
          " unexpected bytes after the last element (the header does not match the data)"));
    }
    return absl::OkStatus();
  }

  // An error for the last failure, or for `message` at the current position.
  absl::Status error(absl::string_view name, absl::string_view context,
                     absl::string_view message = {}) const {
    if (!message.empty()) {
      return absl::InvalidArgumentError(
          absl::StrCat(name, ": byte offset ", item_pos_, ": ", context, ": ", message));
    }
    return absl::InvalidArgumentError(
        absl::StrCat(name, ": byte offset ", problem_pos_, ": ", context, ": ", problem_));
  }

  // Marks the start of an item, so value errors can point at it.
  void begin_item() { item_pos_ = pos_; }

 private:
  template <typename T, typename Out>
  bool load(Out* out) {
    if (sizeof(T) > bytes_.size() - pos_) {
      problem_pos_ = pos_;
      problem_ = absl::StrCat("unexpected end of data (need ", sizeof(T), " bytes, ",
                              bytes_.size() - pos_, " remain)");
      return false;
    }
    unsigned char raw[sizeof(T)];
    std::memcpy(raw, bytes_.data() + pos_, sizeof(T));
    if (swap_) std::reverse(raw, raw + sizeof(T));
    T value;
    std::memcpy(&value, raw, sizeof(T));
    *out = static_cast<Out>(value);
    pos_ += sizeof(T);
    return true;
  }

  absl::string_view bytes_;
  std::size_t pos_;
  bool swap_;
  std::size_t item_pos_ = 0;
  std::size_t problem_pos_ = 0;
  std::string problem_;
};

// Reads whitespace-separated ascii values, counting lines for error messages.
class AsciiReader {
 public:
  AsciiReader(absl::string_view bytes, std::size_t pos, std::size_t line)
      : bytes_(bytes), pos_(pos), line_(line) {}

  bool read_number(ScalarType type, double* out) {
    if (is_integer(type)) {
      std::int64_t value = 0;
      if (!read_integer(type, &value)) return false;
      *out = static_cast<double>(value);
      return true;
    }
    absl::string_view token;
    if (!next_token(&token)) return false;
    double value = 0.0;
    auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), value);
    if (ec != std::errc() || end != token.data() + token.size()) {
      return fail(absl::StrCat("'", token, "' is not a number"));
    }
    *out = value;
    return true;
  }

  bool read_integer(ScalarType type, std::int64_t* out) {
    absl::string_view token;
    if (!next_token(&token)) return false;
    std::int64_t value = 0;
    auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), value);
    if (ec != std::errc() || end != token.data() + token.size()) {
      return fail(absl::StrCat("'", token, "' is not an integer"));
    }
    auto [lo, hi] = integer_range(type);
    if (value < lo || value > hi) {
      return fail(absl::StrCat("'", token, "' is out of range for its property type"));
    }
    *out = value;
    return true;
  }

  bool skip(ScalarType type, std::uint64_t n) {
    double ignored = 0.0;
    for (std::uint64_t i = 0; i < n; ++i) {
      if (!read_number(type, &ignored)) return false;
    }
    return true;
  }

  absl::Status finish(absl::string_view name) {
    skip_space();
    if (pos_ != bytes_.size()) {
      return absl::InvalidArgumentError(
          absl::StrCat(name, ":", line_,
                       ": unexpected data after the last element (the header does not match "
                       "the data)"));
    }
    return absl::OkStatus();
  }

  absl::Status error(absl::string_view name, absl::string_view context,
                     absl::string_view message = {}) const {
    if (!message.empty()) {
      return absl::InvalidArgumentError(
          absl::StrCat(name, ":", item_line_, ": ", context, ": ", message));
    }
    return absl::InvalidArgumentError(
        absl::StrCat(name, ":", problem_line_, ": ", context, ": ", problem_));
  }

  void begin_item() {
    skip_space();
    item_line_ = line_;
  }

 private:
  static std::pair<std::int64_t, std::int64_t> integer_range(ScalarType type) {
    PRISM_CHECK(is_integer(type));
    return with_type(type, [](auto v) -> std::pair<std::int64_t, std::int64_t> {
      using T = decltype(v);
      if constexpr (std::is_integral_v<T>) {
        return {std::numeric_limits<T>::min(), std::numeric_limits<T>::max()};
      } else {
        return {0, -1};
      }
    });
  }

  void skip_space() {
    while (pos_ < bytes_.size()) {
      char c = bytes_[pos_];
      if (c == '\n') {
        ++line_;
      } else if (c != ' ' && c != '\t' && c != '\r') {
        break;
      }
      ++pos_;
    }
  }

  bool next_token(absl::string_view* token) {
    skip_space();
    if (pos_ == bytes_.size()) return fail("unexpected end of file");
    std::size_t start = pos_;
    while (pos_ < bytes_.size()) {
      char c = bytes_[pos_];
      if (c == ' ' || c == '\t' || c == '\r' || c == '\n') break;
      ++pos_;
    }
    *token = bytes_.substr(start, pos_ - start);
    return true;
  }

  bool fail(std::string message) {
    problem_line_ = line_;
    problem_ = std::move(message);
    return false;
  }

  absl::string_view bytes_;
  std::size_t pos_;
  std::size_t line_;
  std::size_t item_line_ = 0;
  std::size_t problem_line_ = 0;
  std::string problem_;
};

std::string item_context(const Element& e, std::uint64_t index) {
  return absl::StrCat("'", e.name, "' item ", index);
}

template <typename Reader>
absl::Status skip_property(Reader& reader, const Property& p, const Element& e, std::uint64_t index,
                           absl::string_view name) {
  if (!p.is_list) {
    double ignored = 0.0;
    if (!reader.read_number(p.type, &ignored)) return reader.error(name, item_context(e, index));
    return absl::OkStatus();
  }
  std::int64_t count = 0;
  if (!reader.read_integer(p.count_type, &count)) return reader.error(name, item_context(e, index));
  if (count < 0) {
    return reader.error(name, item_context(e, index),
                        absl::StrCat("list '", p.name, "' has negative length ", count));
  }
  if (!reader.skip(p.type, static_cast<std::uint64_t>(count))) {
    return reader.error(name, item_context(e, index));
  }
  return absl::OkStatus();
}

template <typename Reader>
absl::Status read_vertices(Reader& reader, const Element& e, absl::string_view name,
                           TriangleMeshData& mesh) {
  bool has_normals = false;
  bool has_uvs = false;
  for (const Property& p : e.properties) {
    has_normals |= p.role == Role::kNx;
    has_uvs |= p.role == Role::kU;
  }
  mesh.positions.reserve(e.count);
  if (has_normals) mesh.normals.reserve(e.count);
  if (has_uvs) mesh.uvs.reserve(e.count);
  constexpr absl::string_view kRoleNames[kVertexRoles] = {"x",  "y",  "z", "nx",
                                                          "ny", "nz", "u", "v"};
  float values[kVertexRoles] = {};
  for (std::uint64_t i = 0; i < e.count; ++i) {
    reader.begin_item();
    for (const Property& p : e.properties) {
      if (p.role == Role::kSkip) {
        PRISM_RETURN_IF_ERROR(skip_property(reader, p, e, i, name));
        continue;
      }
      double value = 0.0;
      if (!reader.read_number(p.type, &value)) return reader.error(name, item_context(e, i));
      // Converting a finite double beyond float range is undefined behaviour, so refuse it here.
      if (!std::isfinite(value) || std::fabs(value) > std::numeric_limits<float>::max()) {
        int role = static_cast<int>(p.role);
        return reader.error(
            name, item_context(e, i),
            absl::StrCat("'", kRoleNames[role], "' is ", value, ", not a finite float"));
      }
      values[static_cast<int>(p.role)] = static_cast<float>(value);
    }
    mesh.positions.push_back({values[0], values[1], values[2]});
    if (has_normals) mesh.normals.push_back({values[3], values[4], values[5]});
    if (has_uvs) mesh.uvs.push_back({values[6], values[7]});
  }
  return absl::OkStatus();
}

template <typename Reader>
absl::Status read_faces(Reader& reader, const Element& e, std::uint64_t vertex_count,
                        absl::string_view name, const MeshLimits& limits, TriangleMeshData& mesh) {
  mesh.triangles.reserve(e.count);
  std::uint32_t corners[4] = {};
  for (std::uint64_t i = 0; i < e.count; ++i) {
    reader.begin_item();
    for (const Property& p : e.properties) {
      if (p.role != Role::kFaceIndices) {
        PRISM_RETURN_IF_ERROR(skip_property(reader, p, e, i, name));
        continue;
      }
      std::int64_t n = 0;
      if (!reader.read_integer(p.count_type, &n)) return reader.error(name, item_context(e, i));
      if (n < 3 || n > 4) {
        return reader.error(
            name, item_context(e, i),
            absl::StrCat("face has ", n, " vertices; only triangles and quads are supported"));
      }
      for (std::int64_t c = 0; c < n; ++c) {
        std::int64_t index = 0;
        if (!reader.read_integer(p.type, &index)) return reader.error(name, item_context(e, i));
        if (index < 0 || static_cast<std::uint64_t>(index) >= vertex_count) {
          return reader.error(name, item_context(e, i),
                              absl::StrCat("vertex index ", index, " is out of range (",
                                           vertex_count, " vertices)"));
        }
        corners[c] = static_cast<std::uint32_t>(index);
      }
      // A quad (c0, c1, c2, c3) is pbrt-v4's bilinear patch p00 = c0, p10 = c1, p11 = c2,
      // p01 = c3, split as mesh.h's patches are.
      if (n == 4) mesh.patches.push_back(static_cast<std::uint32_t>(mesh.triangles.size()));
      mesh.triangles.push_back({corners[0], corners[1], corners[2]});
      if (n == 4) mesh.triangles.push_back({corners[0], corners[2], corners[3]});
      if (mesh.triangles.size() > limits.max_triangles) {
        return absl::ResourceExhaustedError(
            absl::StrCat(name, ": more than ", limits.max_triangles,
                         " triangles after splitting quads, over the limit"));
      }
    }
  }
  return absl::OkStatus();
}

template <typename Reader>
absl::Status read_body(Reader& reader, const Header& header, const Element& vertex,
                       absl::string_view name, const MeshLimits& limits, TriangleMeshData& mesh) {
  for (const Element& e : header.elements) {
    if (&e == &vertex) {
      PRISM_RETURN_IF_ERROR(read_vertices(reader, e, name, mesh));
    } else if (e.name == "face") {
      PRISM_RETURN_IF_ERROR(read_faces(reader, e, vertex.count, name, limits, mesh));
    } else if (!e.properties.empty()) {
      for (std::uint64_t i = 0; i < e.count; ++i) {
        reader.begin_item();
        for (const Property& p : e.properties) {
          PRISM_RETURN_IF_ERROR(skip_property(reader, p, e, i, name));
        }
      }
    }
  }
  return reader.finish(name);
}

}  // namespace

absl::StatusOr<TriangleMeshData> parse_ply(std::string_view bytes_in, std::string_view name_in,
                                           const MeshLimits& limits) {
  absl::string_view bytes(bytes_in.data(), bytes_in.size());
  absl::string_view name(name_in.data(), name_in.size());
  if (bytes.size() > limits.max_file_bytes) {
    return absl::ResourceExhaustedError(absl::StrCat(
        name, ": ", bytes.size(), " bytes, over the limit of ", limits.max_file_bytes));
  }
  PRISM_ASSIGN_OR_RETURN(Header header, parse_header(bytes, name));
  Element* vertex = nullptr;
  Element* face = nullptr;
  PRISM_RETURN_IF_ERROR(assign_roles(header, name, &vertex, &face));
  std::uint64_t max_vertices =
      std::min<std::uint64_t>(limits.max_vertices, std::numeric_limits<std::uint32_t>::max());
  if (vertex->count > max_vertices) {
    return absl::ResourceExhaustedError(
        absl::StrCat(name, ": ", vertex->count, " vertices, over the limit of ", max_vertices));
  }
  if (face->count > limits.max_triangles) {
    return absl::ResourceExhaustedError(absl::StrCat(
        name, ": ", face->count, " faces, over the limit of ", limits.max_triangles, " triangles"));
  }
  PRISM_RETURN_IF_ERROR(check_counts_fit(header, bytes.size() - header.body_offset, name));

  TriangleMeshData mesh;
  if (header.format == Format::kAscii) {
    AsciiReader reader(bytes, header.body_offset, header.body_first_line);
    PRISM_RETURN_IF_ERROR(read_body(reader, header, *vertex, name, limits, mesh));
  } else {
    BinaryReader reader(bytes, header.body_offset, header.format == Format::kBinaryBigEndian);
    PRISM_RETURN_IF_ERROR(read_body(reader, header, *vertex, name, limits, mesh));
  }
  absl::Status valid = mesh.validate();
  if (!valid.ok()) return absl::InvalidArgumentError(absl::StrCat(name, ": ", valid.message()));
  return mesh;
}

absl::StatusOr<TriangleMeshData> load_ply(const std::filesystem::path& path,
                                          const MeshLimits& limits) {
  PRISM_ASSIGN_OR_RETURN(std::string bytes, base::read_file(path, limits.max_file_bytes));
  return parse_ply(bytes, path.string(), limits);
}

}  // namespace prism::scene
