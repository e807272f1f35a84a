#include "services/scene/parser.h"

#include <algorithm>
#include <cctype>
#include <map>
#include <optional>
#include <set>
#include <utility>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "services/base/status.h"
#include "services/image/texture_image.h"
#include "services/scene/coordinate_range.h"
#include "services/scene/mesh_obj.h"
#include "services/scene/mesh_ply.h"
#include "services/scene/parameters.h"
#include "services/scene/path_guard.h"
#include "services/scene/scene_entities.h"
#include "services/scene/tokenizer.h"

namespace prism::scene {
namespace {

// pbrt-v4's pair of current transforms, at the shutter's open and close.
struct TransformPair {
  Transform start, end;
  bool moves() const { return !(start == end); }
};

struct GraphicsState {
  // Transform directives change the active ones (`ActiveTransform`). An entity whose two
  // transforms differ moves during the shutter interval: a moving shape, instance or camera is
  // refused (Prism does not render motion blur), and a light or texture takes its start
  // transform, as pbrt-v4 does.
  TransformPair ctm;
  bool start_active = true;
  bool end_active = true;
  bool reverse_orientation = false;
  int material = -1;  // -1: pbrt-v4's default material (diffuse, reflectance 0.5)
  std::optional<AreaLight> area_light;
  int inside_medium = -1;
  int outside_medium = -1;
};

enum class ScopeKind { kAttribute, kObject };

struct Scope {
  ScopeKind kind;
  GraphicsState saved;
  SourceLocation where;
  const char* begin = nullptr;  // the directive that opened it, for messages (scope_begin_name)
};

struct ObjectDefinition {
  std::vector<Shape> shapes;
  SourceLocation where;
};

const char* scope_begin_name(ScopeKind kind) {
  switch (kind) {
    case ScopeKind::kAttribute:
      return "AttributeBegin";
    case ScopeKind::kObject:
      return "ObjectBegin";
  }
  return "";
}

// pbrt-v4's `Option` directive: the options it knows, the kind of value each takes, and what
// each does to the image. Those that only affect speed, statistics or output files cannot change
// it; `disabletexturefiltering` is what Prism does anyway; false is every boolean option's
// default; the rest change the image and are refused.
struct PbrtOption {
  std::string_view name;
  enum class Value { kBool, kInteger, kOther } value;
  enum class Effect { kNone, kPrismDoesIt, kChangesTheImage } effect;
};
constexpr PbrtOption kPbrtOptions[] = {
    {"seed", PbrtOption::Value::kInteger, PbrtOption::Effect::kNone},
    {"quickrender", PbrtOption::Value::kBool, PbrtOption::Effect::kNone},
    {"quiet", PbrtOption::Value::kBool, PbrtOption::Effect::kNone},
    {"rendercoordsys", PbrtOption::Value::kOther, PbrtOption::Effect::kNone},
    {"wavefront", PbrtOption::Value::kBool, PbrtOption::Effect::kNone},
    {"msereferenceimage", PbrtOption::Value::kOther, PbrtOption::Effect::kNone},
    {"msereferenceout", PbrtOption::Value::kOther, PbrtOption::Effect::kNone},
    {"displacementedgescale", PbrtOption::Value::kOther, PbrtOption::Effect::kNone},
    {"recordpixelstatistics", PbrtOption::Value::kBool, PbrtOption::Effect::kNone},
    {"useGPU", PbrtOption::Value::kBool, PbrtOption::Effect::kNone},
    {"disabletexturefiltering", PbrtOption::Value::kBool, PbrtOption::Effect::kPrismDoesIt},
    {"disablepixeljitter", PbrtOption::Value::kBool, PbrtOption::Effect::kChangesTheImage},
    {"disablewavelengthjitter", PbrtOption::Value::kBool, PbrtOption::Effect::kChangesTheImage},
    {"forcediffuse", PbrtOption::Value::kBool, PbrtOption::Effect::kChangesTheImage},
};

const PbrtOption* find_pbrt_option(std::string_view name) {
  for (const PbrtOption& o : kPbrtOptions) {
    if (o.name == name) return &o;
  }
  return nullptr;
}

// Records or refuses the option `name` (unknown names, which only the typed form lets through,
// are refused as changing the image). `feature` names it for reports.
absl::Status apply_option(const std::string& name, bool is_false, const std::string& feature,
                          const SourceLocation& where, FeatureRecorder& features) {
  const PbrtOption* option = find_pbrt_option(name);
  const PbrtOption::Effect effect =
      option != nullptr ? option->effect : PbrtOption::Effect::kChangesTheImage;
  if (effect == PbrtOption::Effect::kNone) {
    features.ignored(feature, where, "does not change the converged image");
  } else if (effect == PbrtOption::Effect::kPrismDoesIt) {
    features.supported(feature, where, "Prism never prefilters textures");
  } else if (is_false) {
    features.ignored(feature, where, "false is pbrt-v4's default");
  } else {
    PRISM_RETURN_IF_ERROR(features.refuse(
        feature, where,
        absl::StrCat("Option '", name, "' changes the image and is not supported by Prism"),
        "the scene without the option"));
  }
  return absl::OkStatus();
}

// The typed form, `Option "bool name" value`, which Prism has always read.
absl::Status apply_options(const ParameterList& params, FeatureRecorder& features) {
  for (const Parameter& p : params.parameters()) {
    p.used = true;
    PRISM_RETURN_IF_ERROR(
        apply_option(p.name, p.type == ParamType::kBool && p.bools.size() == 1 && !p.bools[0],
                     params.feature(p), p.where, features));
  }
  return absl::OkStatus();
}

class SceneParser {
 public:
  SceneParser(const LoadOptions& options, const SceneFiles& files)
      : options_(options), files_(files), features_(options.allow_unsupported, &scene_.features) {
    ctx_.spectra.is_known_spectrum = options.is_known_spectrum;
    ctx_.spectra.is_known_ior = options.is_known_ior;
    ctx_.spectra.load_table = [this](const std::string& ref, const SourceLocation& where) {
      return load_table(ref, where);
    };
    ctx_.mesh_limits = options.mesh_limits;
    ctx_.find_material = [this](const std::string& name) -> std::optional<int> {
      auto it = named_materials_.find(name);
      if (it == named_materials_.end()) return std::nullopt;
      return it->second;
    };
    ctx_.load_mesh = [this](const std::string& ref, MeshFormat format,
                            const SourceLocation& where) { return load_mesh(ref, format, where); };
    ctx_.find_texture = [this](const std::string& name, bool spectrum,
                               const SourceLocation& where) -> std::optional<int> {
      const auto& names = spectrum ? spectrum_textures_ : float_textures_;
      if (auto it = names.find(name); it != names.end()) return it->second;
      // A texture names only earlier ones (pbrt-v4 creates them in order); a name of the other
      // kind is the caller's error to report.
      if (reading_texture_ || (spectrum ? float_textures_ : spectrum_textures_).contains(name))
        return std::nullopt;
      // A material or shape naming a texture defined further on: a slot its Texture fills.
      auto [pending, added] = pending_textures_.try_emplace({name, spectrum});
      if (added) {
        pending->second = {static_cast<int>(scene_.textures.size()), where};
        scene_.textures.push_back(Texture{name, spectrum, ConstantTexture{}, where});
      }
      return pending->second.index;
    };
    ctx_.load_image = [this](const std::string& ref, const SourceLocation& where) {
      return load_image(ref, where);
    };
  }

  absl::StatusOr<SceneDescription> run(std::string_view text, const std::string& relpath) {
    record_file(relpath);
    open_files_.push_back(relpath);
    PRISM_RETURN_IF_ERROR(parse_file(text, relpath, 0));
    SourceLocation end{relpath, end_line_, end_column_};
    if (!in_world_) return location_error(end, "end of file before WorldBegin");
    if (current_object_)
      return location_error(
          objects_[*current_object_].where,
          absl::StrCat("ObjectBegin \"", *current_object_, "\" is never closed by ObjectEnd"));
    for (const Scope& s : scopes_)
      scene_.warnings.push_back(absl::StrCat(
          s.where.to_string(), ": warning: ",
          s.begin != nullptr ? s.begin : scope_begin_name(s.kind), " is never closed"));
    // Instances of objects defined after them.
    for (const PendingInstance& instance : pending_instances_) {
      auto it = objects_.find(instance.name);
      if (it == objects_.end()) {
        return location_error(instance.name_at, absl::StrCat("object \"", instance.name,
                                                             "\" is not defined anywhere in the "
                                                             "scene"));
      }
      PRISM_RETURN_IF_ERROR(instantiate(it->second, instance.ctm, instance.where));
    }
    // Textures named before their Texture directive.
    for (const auto& [key, pending] : pending_textures_) {
      const auto& [texture_name, spectrum] = key;
      std::string other;
      const auto& others = spectrum ? float_textures_ : spectrum_textures_;
      if (auto it = others.find(texture_name); it != others.end())
        other = absl::StrCat(" (the texture of that name at ",
                             scene_.textures[static_cast<size_t>(it->second)].where.to_string(),
                             " is a ", spectrum ? "float" : "spectrum", " texture)");
      return location_error(
          pending.first_use,
          absl::StrCat(spectrum ? "spectrum" : "float", " texture \"", texture_name,
                       "\" is not defined anywhere in the scene", other));
    }
    // Materials named before their MakeNamedMaterial (NamedMaterial's pending names): each must
    // be defined by the end, used or not.
    for (const auto& [material_name, named_at] : pending_materials_) {
      if (!named_materials_.contains(material_name)) {
        return location_error(named_at, absl::StrCat("named material \"", material_name,
                                                     "\" is not defined anywhere in the scene"));
      }
    }
    for (Shape& shape : scene_.shapes) {
      if (shape.material > -2) continue;
      const auto& [material_name, named_at] =
          pending_materials_[static_cast<std::size_t>(-2 - shape.material)];
      (void)named_at;
      shape.material = named_materials_.at(material_name);
    }
    const bool lit = !scene_.lights.empty() ||
                     std::any_of(scene_.shapes.begin(), scene_.shapes.end(),
                                 [](const Shape& s) { return s.area_light.has_value(); });
    if (!lit) {
      scene_.warnings.push_back(absl::StrCat(
          relpath,
          ": warning: the scene has no light that emits (LightSource or AreaLightSource): "
          "the image is black"));
    }
    PRISM_RETURN_IF_ERROR(check_coordinate_range(scene_));
    return std::move(scene_);
  }

 private:
  absl::Status parse_file(std::string_view text, const std::string& relpath, int depth);
  absl::Status directive(Tokenizer& tokens, const Token& name, int depth);

  // Arguments of directives.
  absl::StatusOr<std::vector<double>> numbers(Tokenizer& tokens, size_t count,
                                              const Token& directive, bool allow_brackets);
  absl::StatusOr<Token> string_arg(Tokenizer& tokens, const Token& directive, const char* what);

  absl::Status require_world(const Token& directive, const SourceLocation& where) const {
    if (!in_world_)
      return location_error(
          where, absl::StrCat("'", directive.text, "' is only allowed after WorldBegin"));
    return absl::OkStatus();
  }
  absl::Status require_options(const Token& directive, const SourceLocation& where) const {
    if (in_world_)
      return location_error(where,
                            absl::StrCat("'", directive.text, "' is not allowed after WorldBegin"));
    return absl::OkStatus();
  }
  absl::Status once(std::optional<SourceLocation>& seen, const Token& directive,
                    const SourceLocation& where) {
    if (seen)
      return location_error(where, absl::StrCat("'", directive.text, "' given twice (first at ",
                                                seen->to_string(), ")"));
    seen = where;
    return absl::OkStatus();
  }

  // The files being parsed, outermost first: an Include of one of them is a cycle.
  std::vector<std::string> open_files_;
  // Names given to NamedMaterial before their MakeNamedMaterial, and where (resolved in run()).
  std::vector<std::pair<std::string, SourceLocation>> pending_materials_;
  // ObjectInstance of an object not (yet) defined: expanded at the end of the scene.
  struct PendingInstance {
    std::string name;
    Transform ctm;  // the start transform (a moving instance is refused where it is used)
    SourceLocation where, name_at;
  };
  std::vector<PendingInstance> pending_instances_;
  // Textures named by a material or shape before their Texture directive: the slot in
  // scene_.textures the directive fills, and the first use (resolved in run()).
  struct PendingTexture {
    int index = -1;
    SourceLocation first_use;
  };
  std::map<std::pair<std::string, bool>, PendingTexture> pending_textures_;
  bool reading_texture_ = false;  // inside a Texture directive's parameters

  // The object's shapes, placed by `ctm`, as the ObjectInstance at `where`.
  absl::Status instantiate(const ObjectDefinition& object, const Transform& ctm,
                           const SourceLocation& where) {
    for (const Shape& s : object.shapes) {
      Shape copy = s;
      copy.object_to_world = ctm * s.object_to_world;
      copy.transform_swaps_handedness = copy.object_to_world.swaps_handedness();
      copy.where = where;
      PRISM_RETURN_IF_ERROR(add_shape(std::move(copy)));
    }
    return absl::OkStatus();
  }

  void record_file(const std::string& relpath) {
    if (recorded_.insert(relpath).second) scene_.files.push_back(relpath);
  }

  absl::StatusOr<std::string> resolve(const std::string& reference,
                                      const SourceLocation& where) const;
  absl::StatusOr<std::string> read(const std::string& relpath, std::uint64_t max_bytes,
                                   const SourceLocation& where) const;
  absl::StatusOr<SpectrumTabulated> load_table(const std::string& reference,
                                               const SourceLocation& where);
  absl::StatusOr<TriangleMeshShape> load_mesh(const std::string& reference, MeshFormat format,
                                              const SourceLocation& where);
  absl::StatusOr<EntityContext::LoadedImage> load_image(const std::string& reference,
                                                        const SourceLocation& where);
  absl::Status count_triangles(const ShapeGeometry& g, const SourceLocation& where);
  int material_index(const SourceLocation& where);
  absl::StatusOr<int> medium_index(const Token& name, const SourceLocation& where) const;
  absl::Status add_shape(Shape shape);

  // A directive's parameters, owned by `owner` (`Material "diffuse"`) for feature reports.
  absl::StatusOr<ParameterList> parameters(Tokenizer& tokens, std::string owner) {
    PRISM_ASSIGN_OR_RETURN(ParameterList params, ParameterList::parse(tokens));
    params.set_policy(&features_, std::move(owner));
    return params;
  }
  // A directive Prism does not run, refused (or, allowing unsupported input, skipped with its
  // arguments: everything up to the next directive name).
  absl::Status skip_directive(Tokenizer& tokens, const Token& d, const SourceLocation& where,
                              const std::string& message);
  // Transform directives change the active transforms only.
  void set_ctm(const Transform& t) {
    if (state_.start_active) state_.ctm.start = t;
    if (state_.end_active) state_.ctm.end = t;
  }
  void apply_to_ctm(const Transform& t) {
    if (state_.start_active) state_.ctm.start = state_.ctm.start * t;
    if (state_.end_active) state_.ctm.end = state_.ctm.end * t;
  }
  // `what` (a directive) placed by the current transforms: an error, or allowing unsupported
  // input a recorded refusal, when they differ.
  absl::Status refuse_motion(std::string_view what, const SourceLocation& where) {
    if (!state_.ctm.moves()) return absl::OkStatus();
    return features_.refuse(
        "motion blur", where,
        absl::StrCat("'", std::string(what),
                     "' moves: its StartTime and EndTime transforms differ (ActiveTransform), "
                     "and Prism does not render motion blur"),
        "the shutter-open (StartTime) transform, without motion");
  }

  const LoadOptions& options_;
  const SceneFiles& files_;
  EntityContext ctx_;
  SceneDescription scene_;
  FeatureRecorder features_;
  GraphicsState state_;
  std::vector<Scope> scopes_;
  std::map<std::string, TransformPair> named_coordinate_systems_;
  std::map<std::string, int> named_materials_;
  std::map<std::string, int> named_media_;
  std::map<std::string, ObjectDefinition> objects_;
  std::optional<std::string> current_object_;
  bool in_world_ = false;
  std::optional<SourceLocation> camera_at_, film_at_, sampler_at_, integrator_at_, filter_at_,
      world_at_;
  int default_material_ = -1;
  std::map<std::string, std::shared_ptr<const TriangleMeshData>> meshes_;
  std::map<std::string, SpectrumTabulated> tables_;
  std::map<std::string, EntityContext::LoadedImage> images_;
  std::map<std::string, int> spectrum_textures_;
  std::map<std::string, int> float_textures_;
  std::set<std::string> recorded_;
  std::uint64_t total_triangles_ = 0;
  int end_line_ = 1;
  int end_column_ = 1;
};

absl::StatusOr<std::string> SceneParser::resolve(const std::string& reference,
                                                 const SourceLocation& where) const {
  if (reference.empty()) return location_error(where, "empty file name");
  if (reference.front() == '/' || reference.front() == '\\' ||
      (reference.size() > 1 && reference[1] == ':'))
    return location_error(
        where, absl::StrCat("absolute path \"", reference,
                            "\" refused: files must be named relative to the scene file"));
  // Relative to the main scene file's directory, whichever file mentions it, as pbrt-v4 resolves
  // every file name (its search directory is set once, from the file it was given).
  const std::string& joined = reference;
  int level = 0;
  for (absl::string_view part : absl::StrSplit(joined, '/')) {
    if (part == "..") {
      if (--level < 0)
        return location_error(where,
                              absl::StrCat("path \"", reference, "\" escapes the scene directory"));
    } else if (!part.empty() && part != ".") {
      ++level;
    }
  }
  absl::StatusOr<std::string> normal = normalize_reference(joined);
  if (!normal.ok()) return located(where, normal.status());
  return *normal;
}

absl::StatusOr<std::string> SceneParser::read(const std::string& relpath, std::uint64_t max_bytes,
                                              const SourceLocation& where) const {
  absl::StatusOr<std::string> text = files_.read(relpath, max_bytes);
  if (!text.ok()) return located(where, text.status());
  return text;
}

absl::StatusOr<SpectrumTabulated> SceneParser::load_table(const std::string& reference,
                                                          const SourceLocation& where) {
  PRISM_ASSIGN_OR_RETURN(std::string relpath, resolve(reference, where));
  if (auto it = tables_.find(relpath); it != tables_.end()) return it->second;
  PRISM_ASSIGN_OR_RETURN(std::string text, read(relpath, options_.max_spectrum_file_bytes, where));
  record_file(relpath);
  PRISM_ASSIGN_OR_RETURN(SpectrumTabulated table, parse_spectrum_table(text, relpath));
  tables_.emplace(relpath, table);
  return table;
}

absl::StatusOr<TriangleMeshShape> SceneParser::load_mesh(const std::string& reference,
                                                         MeshFormat format,
                                                         const SourceLocation& where) {
  PRISM_ASSIGN_OR_RETURN(std::string relpath, resolve(reference, where));
  auto it = meshes_.find(relpath);
  if (it == meshes_.end()) {
    absl::StatusOr<TriangleMeshData> mesh = files_.load_mesh(relpath, format, options_.mesh_limits);
    if (!mesh.ok()) return located(where, mesh.status());
    record_file(relpath);
    it = meshes_.emplace(relpath, std::make_shared<const TriangleMeshData>(std::move(*mesh))).first;
  }
  return TriangleMeshShape{it->second, relpath};
}

absl::StatusOr<EntityContext::LoadedImage> SceneParser::load_image(const std::string& reference,
                                                                   const SourceLocation& where) {
  PRISM_ASSIGN_OR_RETURN(std::string relpath, resolve(reference, where));
  if (auto it = images_.find(relpath); it != images_.end()) return it->second;
  PRISM_ASSIGN_OR_RETURN(std::string bytes, read(relpath, options_.max_image_file_bytes, where));
  absl::StatusOr<image::TextureImageData> decoded = image::decode_texture_image(bytes, relpath);
  if (!decoded.ok()) return located(where, decoded.status());
  record_file(relpath);
  auto image = std::make_shared<TextureImage>();
  image->width = decoded->width;
  image->height = decoded->height;
  image->channels = decoded->channels;
  image->values = std::move(decoded->values);
  EntityContext::LoadedImage loaded{std::move(image), decoded->eight_bit, relpath};
  images_.emplace(relpath, loaded);
  return loaded;
}

absl::Status SceneParser::count_triangles(const ShapeGeometry& g, const SourceLocation& where) {
  if (const auto* mesh = std::get_if<TriangleMeshShape>(&g)) {
    total_triangles_ += mesh->mesh->triangles.size();
    if (total_triangles_ > options_.max_total_triangles)
      return absl::ResourceExhaustedError(absl::StrCat(where.to_string(),
                                                       ": the scene has more than ",
                                                       options_.max_total_triangles, " triangles"));
  }
  return absl::OkStatus();
}

int SceneParser::material_index(const SourceLocation& where) {
  if (state_.material >= 0 || state_.material <= -2) return state_.material;  // -2...: pending
  if (default_material_ < 0) {
    default_material_ = static_cast<int>(scene_.materials.size());
    scene_.materials.push_back(Material{"", DiffuseMaterial{}, where});
  }
  return default_material_;
}

absl::StatusOr<int> SceneParser::medium_index(const Token& name,
                                              const SourceLocation& where) const {
  if (name.text.empty()) return -1;
  auto it = named_media_.find(name.text);
  if (it == named_media_.end())
    return location_error(where, absl::StrCat("medium \"", name.text, "\" is not defined"));
  return it->second;
}

absl::Status SceneParser::skip_directive(Tokenizer& tokens, const Token& d,
                                         const SourceLocation& where, const std::string& message) {
  PRISM_RETURN_IF_ERROR(features_.refuse(absl::StrCat("directive ", d.text), where, message,
                                         "the scene without the directive"));
  // Its arguments are strings, numbers and brackets; the next directive is a word that starts
  // with a letter.
  while (true) {
    PRISM_ASSIGN_OR_RETURN(Token next, tokens.peek());
    if (next.kind == Token::Kind::kEnd) return absl::OkStatus();
    if (next.kind == Token::Kind::kWord && !next.text.empty() &&
        std::isalpha(static_cast<unsigned char>(next.text[0])) && next.text != "true" &&
        next.text != "false")
      return absl::OkStatus();
    PRISM_RETURN_IF_ERROR(tokens.next().status());
  }
}

absl::Status SceneParser::add_shape(Shape shape) {
  if (current_object_) {
    if (shape.area_light) {
      PRISM_RETURN_IF_ERROR(
          features_.refuse("area light inside ObjectBegin", shape.where,
                           "area lights inside ObjectBegin/ObjectEnd are not supported",
                           "the instanced shapes without emission"));
      shape.area_light.reset();
    }
    objects_[*current_object_].shapes.push_back(std::move(shape));
    return absl::OkStatus();
  }
  PRISM_RETURN_IF_ERROR(count_triangles(shape.geometry, shape.where));
  scene_.shapes.push_back(std::move(shape));
  return absl::OkStatus();
}

absl::StatusOr<std::vector<double>> SceneParser::numbers(Tokenizer& tokens, size_t count,
                                                         const Token& directive,
                                                         bool allow_brackets) {
  std::vector<double> out;
  PRISM_ASSIGN_OR_RETURN(Token first, tokens.peek());
  bool bracketed = allow_brackets && first.kind == Token::Kind::kOpenBracket;
  if (bracketed) PRISM_RETURN_IF_ERROR(tokens.next().status());
  for (size_t i = 0; i < count; ++i) {
    PRISM_ASSIGN_OR_RETURN(Token t, tokens.next());
    SourceLocation at = tokens.location(t);
    if (t.kind != Token::Kind::kWord)
      return location_error(
          at, absl::StrCat("'", directive.text, "' needs ", count, " numbers, found ",
                           t.kind == Token::Kind::kString ? absl::StrCat("string \"", t.text, "\"")
                                                          : std::string(token_kind_name(t.kind))));
    PRISM_ASSIGN_OR_RETURN(double v, parse_finite_number(t.text, at, directive.text));
    out.push_back(v);
  }
  if (bracketed) {
    PRISM_ASSIGN_OR_RETURN(Token close, tokens.next());
    if (close.kind != Token::Kind::kCloseBracket)
      return location_error(
          tokens.location(close),
          absl::StrCat("'", directive.text, "' needs exactly ", count, " numbers in [ ]"));
  }
  return out;
}

absl::StatusOr<Token> SceneParser::string_arg(Tokenizer& tokens, const Token& directive,
                                              const char* what) {
  PRISM_ASSIGN_OR_RETURN(Token t, tokens.next());
  if (t.kind != Token::Kind::kString)
    return location_error(
        tokens.location(t),
        absl::StrCat("'", directive.text, "' needs a quoted ", what, ", found ",
                     t.kind == Token::Kind::kWord ? absl::StrCat("'", t.text, "'")
                                                  : std::string(token_kind_name(t.kind))));
  return t;
}

absl::Status SceneParser::parse_file(std::string_view text, const std::string& relpath, int depth) {
  // A UTF-8 byte order mark (editors on Windows write one) is not part of the first directive.
  if (text.starts_with("\xEF\xBB\xBF")) text.remove_prefix(3);
  Tokenizer tokens(text, relpath);
  while (true) {
    PRISM_ASSIGN_OR_RETURN(Token t, tokens.next());
    if (t.kind == Token::Kind::kEnd) {
      if (depth == 0) {
        end_line_ = t.line;
        end_column_ = t.column;
      }
      return absl::OkStatus();
    }
    if (t.kind != Token::Kind::kWord)
      return location_error(
          tokens.location(t),
          absl::StrCat("expected a directive, found ", t.kind == Token::Kind::kString
                                                           ? absl::StrCat("string \"", t.text, "\"")
                                                           : std::string(token_kind_name(t.kind))));
    PRISM_RETURN_IF_ERROR(directive(tokens, t, depth));
  }
}

absl::Status SceneParser::directive(Tokenizer& tokens, const Token& d, int depth) {
  const std::string& name = d.text;
  SourceLocation where = tokens.location(d);

  auto apply = [&](const Transform& t) { apply_to_ctm(t); };
  auto typed_directive = [&]() -> absl::StatusOr<std::pair<TypeName, ParameterList>> {
    PRISM_ASSIGN_OR_RETURN(Token type, string_arg(tokens, d, "type name"));
    PRISM_ASSIGN_OR_RETURN(ParameterList params,
                           parameters(tokens, absl::StrCat(name, " \"", type.text, "\"")));
    return std::make_pair(TypeName{type.text, tokens.location(type)}, std::move(params));
  };

  if (name == "Translate") {
    PRISM_ASSIGN_OR_RETURN(std::vector<double> v, numbers(tokens, 3, d, false));
    apply(Transform::translate({v[0], v[1], v[2]}));
  } else if (name == "Scale") {
    PRISM_ASSIGN_OR_RETURN(std::vector<double> v, numbers(tokens, 3, d, false));
    std::optional<Transform> t = Transform::scale({v[0], v[1], v[2]});
    if (!t) return location_error(where, "'Scale' with a zero factor makes the transform singular");
    apply(*t);
  } else if (name == "Rotate") {
    PRISM_ASSIGN_OR_RETURN(std::vector<double> v, numbers(tokens, 4, d, false));
    std::optional<Transform> t = Transform::rotate(v[0], {v[1], v[2], v[3]});
    if (!t) return location_error(where, "'Rotate' needs a non-zero axis");
    apply(*t);
  } else if (name == "LookAt") {
    PRISM_ASSIGN_OR_RETURN(std::vector<double> v, numbers(tokens, 9, d, false));
    std::optional<Transform> t =
        Transform::look_at({v[0], v[1], v[2]}, {v[3], v[4], v[5]}, {v[6], v[7], v[8]});
    if (!t)
      return location_error(where,
                            "'LookAt' needs distinct eye and look points and an up vector "
                            "not parallel to the view direction");
    apply(*t);
  } else if (name == "Transform" || name == "ConcatTransform") {
    PRISM_ASSIGN_OR_RETURN(std::vector<double> v, numbers(tokens, 16, d, true));
    // The 16 numbers are the matrix column by column (pbrt transposes them).
    Matrix4 m{};
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) m[j][i] = v[static_cast<size_t>(i * 4 + j)];
    std::optional<Transform> t = Transform::from_matrix(m);
    if (!t) return location_error(where, absl::StrCat("'", name, "' matrix is singular"));
    if (name == "Transform")
      set_ctm(*t);
    else
      apply(*t);
  } else if (name == "Identity") {
    set_ctm(Transform());
  } else if (name == "CoordinateSystem") {
    PRISM_ASSIGN_OR_RETURN(Token n, string_arg(tokens, d, "name"));
    named_coordinate_systems_[n.text] = state_.ctm;
  } else if (name == "CoordSysTransform") {
    PRISM_ASSIGN_OR_RETURN(Token n, string_arg(tokens, d, "name"));
    auto it = named_coordinate_systems_.find(n.text);
    if (it == named_coordinate_systems_.end())
      return location_error(tokens.location(n),
                            absl::StrCat("coordinate system \"", n.text, "\" is not defined"));
    state_.ctm = it->second;  // both transforms, whichever are active (as pbrt-v4)
  } else if (name == "ActiveTransform") {
    PRISM_ASSIGN_OR_RETURN(Token which, tokens.next());
    SourceLocation at = tokens.location(which);
    if (which.kind != Token::Kind::kWord ||
        (which.text != "All" && which.text != "StartTime" && which.text != "EndTime"))
      return location_error(at, "'ActiveTransform' takes All, StartTime or EndTime");
    state_.start_active = which.text != "EndTime";
    state_.end_active = which.text != "StartTime";
  } else if (name == "ReverseOrientation") {
    PRISM_RETURN_IF_ERROR(require_world(d, where));
    state_.reverse_orientation = !state_.reverse_orientation;
  } else if (name == "Camera") {
    PRISM_RETURN_IF_ERROR(require_options(d, where));
    PRISM_RETURN_IF_ERROR(once(camera_at_, d, where));
    PRISM_ASSIGN_OR_RETURN(auto td, typed_directive());
    PRISM_ASSIGN_OR_RETURN(Camera camera, make_camera(td.first, td.second));
    PRISM_RETURN_IF_ERROR(refuse_motion("Camera", where));
    camera.world_from_camera = state_.ctm.start.inverse();
    camera.medium = state_.outside_medium;
    named_coordinate_systems_["camera"] = {camera.world_from_camera, state_.ctm.end.inverse()};
    scene_.camera = std::move(camera);
  } else if (name == "Film") {
    PRISM_RETURN_IF_ERROR(require_options(d, where));
    PRISM_RETURN_IF_ERROR(once(film_at_, d, where));
    PRISM_ASSIGN_OR_RETURN(auto td, typed_directive());
    PRISM_ASSIGN_OR_RETURN(scene_.film, make_film(td.first, td.second));
  } else if (name == "Sampler") {
    PRISM_RETURN_IF_ERROR(require_options(d, where));
    PRISM_RETURN_IF_ERROR(once(sampler_at_, d, where));
    PRISM_ASSIGN_OR_RETURN(auto td, typed_directive());
    PRISM_ASSIGN_OR_RETURN(scene_.sampler, make_sampler(td.first, td.second));
  } else if (name == "Integrator") {
    PRISM_RETURN_IF_ERROR(require_options(d, where));
    PRISM_RETURN_IF_ERROR(once(integrator_at_, d, where));
    PRISM_ASSIGN_OR_RETURN(auto td, typed_directive());
    PRISM_ASSIGN_OR_RETURN(scene_.integrator, make_integrator(td.first, td.second));
  } else if (name == "PixelFilter") {
    PRISM_RETURN_IF_ERROR(require_options(d, where));
    PRISM_RETURN_IF_ERROR(once(filter_at_, d, where));
    PRISM_ASSIGN_OR_RETURN(auto td, typed_directive());
    PRISM_ASSIGN_OR_RETURN(scene_.filter, make_pixel_filter(td.first, td.second));
  } else if (name == "ColorSpace") {
    PRISM_ASSIGN_OR_RETURN(Token n, string_arg(tokens, d, "colour space name"));
    // pbrt-v4's named colour spaces; another name is a mistake, not a space to substitute.
    if (n.text != "srgb" && n.text != "rec2020" && n.text != "aces2065-1" && n.text != "dci-p3")
      return location_error(tokens.location(n),
                            absl::StrCat("unknown colour space \"", n.text,
                                         "\" (pbrt-v4's: srgb, rec2020, aces2065-1, dci-p3; "
                                         "Prism reads srgb)"));
    if (n.text != "srgb")
      PRISM_RETURN_IF_ERROR(features_.refuse(
          absl::StrCat("ColorSpace \"", n.text, "\""), tokens.location(n),
          absl::StrCat("unsupported colour space \"", n.text, "\" (supported: srgb)"),
          "RGB values read as sRGB"));
  } else if (name == "Option") {
    // pbrt-v4's parser reads `Option "name" value`, untyped (`Option "disablepixeljitter" true`,
    // `Option "rendercoordsys" "world"`); Prism took only the typed parameter form, which pbrt-v4
    // does not know. Both are read.
    PRISM_ASSIGN_OR_RETURN(Token first, tokens.peek());
    if (first.kind == Token::Kind::kString && first.text.find(' ') == std::string::npos) {
      PRISM_RETURN_IF_ERROR(tokens.next().status());
      const SourceLocation at = tokens.location(first);
      PRISM_ASSIGN_OR_RETURN(Token value, tokens.next());
      if (value.kind != Token::Kind::kWord && value.kind != Token::Kind::kString) {
        return location_error(tokens.location(value),
                              absl::StrCat("'Option \"", first.text, "\"' needs a value"));
      }
      // pbrt-v4 knows these options and refuses any other name, and a value of the wrong kind.
      const PbrtOption* option = find_pbrt_option(first.text);
      if (option == nullptr) {
        return location_error(at, absl::StrCat("unknown option \"", first.text, "\""));
      }
      if (option->value == PbrtOption::Value::kBool &&
          (value.kind != Token::Kind::kWord || (value.text != "true" && value.text != "false"))) {
        return location_error(tokens.location(value),
                              absl::StrCat("Option \"", first.text, "\" takes true or false, not '",
                                           value.text, "'"));
      }
      std::int64_t integer = 0;
      if (option->value == PbrtOption::Value::kInteger &&
          (value.kind != Token::Kind::kWord || !absl::SimpleAtoi(value.text, &integer))) {
        return location_error(
            tokens.location(value),
            absl::StrCat("Option \"", first.text, "\" takes an integer, not '", value.text, "'"));
      }
      PRISM_RETURN_IF_ERROR(apply_option(first.text,
                                         value.kind == Token::Kind::kWord && value.text == "false",
                                         absl::StrCat("Option '", first.text, "'"), at, features_));
    } else {
      PRISM_ASSIGN_OR_RETURN(ParameterList params, parameters(tokens, "Option"));
      PRISM_RETURN_IF_ERROR(apply_options(params, features_));
    }
  } else if (name == "WorldBegin") {
    if (in_world_)
      return location_error(
          where, absl::StrCat("'WorldBegin' given twice (first at ", world_at_->to_string(), ")"));
    in_world_ = true;
    world_at_ = where;
    state_.ctm = {};
    state_.start_active = state_.end_active = true;
    named_coordinate_systems_["world"] = state_.ctm;
  } else if (name == "AttributeBegin" || name == "TransformBegin") {
    PRISM_RETURN_IF_ERROR(require_world(d, where));
    // pbrt-v4's parser reads the deprecated TransformBegin/End as AttributeBegin/End: they save
    // and restore every attribute (material, lights, media, orientation), not the transform
    // alone, and either end closes either begin (pbrt --upgrade keeps them as they are).
    if (name == "TransformBegin")
      features_.supported("TransformBegin", where,
                          "deprecated in pbrt-v4, which reads it as AttributeBegin; so does Prism");
    scopes_.push_back(Scope{ScopeKind::kAttribute, state_, where,
                            name == "TransformBegin" ? "TransformBegin" : "AttributeBegin"});
  } else if (name == "AttributeEnd" || name == "TransformEnd") {
    PRISM_RETURN_IF_ERROR(require_world(d, where));
    if (scopes_.empty())
      return location_error(where,
                            absl::StrCat("unmatched '", name, "' (no AttributeBegin is open)"));
    if (scopes_.back().kind != ScopeKind::kAttribute)
      return location_error(
          where, absl::StrCat("'", name, "' closes the ", scope_begin_name(scopes_.back().kind),
                              " at ", scopes_.back().where.to_string()));
    state_ = scopes_.back().saved;
    scopes_.pop_back();
  } else if (name == "Shape") {
    PRISM_RETURN_IF_ERROR(require_world(d, where));
    PRISM_ASSIGN_OR_RETURN(auto td, typed_directive());
    Shape shape;
    PRISM_RETURN_IF_ERROR(read_shape_alpha(td.second, ctx_, &shape.alpha, &shape.alpha_texture));
    PRISM_ASSIGN_OR_RETURN(std::optional<ShapeGeometry> geometry,
                           make_shape_geometry(td.first, td.second, ctx_));
    if (!geometry) return absl::OkStatus();  // refused and dropped (allow_unsupported)
    shape.geometry = std::move(*geometry);
    PRISM_RETURN_IF_ERROR(refuse_motion("Shape", where));
    shape.object_to_world = state_.ctm.start;
    shape.transform_swaps_handedness = state_.ctm.start.swaps_handedness();
    shape.reverse_orientation = state_.reverse_orientation;
    shape.material = material_index(where);
    shape.area_light = state_.area_light;
    shape.media = {state_.inside_medium, state_.outside_medium};
    shape.where = where;
    PRISM_RETURN_IF_ERROR(add_shape(std::move(shape)));
  } else if (name == "Material") {
    PRISM_RETURN_IF_ERROR(require_world(d, where));
    PRISM_ASSIGN_OR_RETURN(auto td, typed_directive());
    PRISM_ASSIGN_OR_RETURN(MaterialKind kind, make_material(td.first, td.second, ctx_));
    state_.material = static_cast<int>(scene_.materials.size());
    scene_.materials.push_back(Material{"", std::move(kind), where});
  } else if (name == "MakeNamedMaterial" || name == "MakeNamedMedium") {
    bool is_material = name == "MakeNamedMaterial";
    if (is_material) PRISM_RETURN_IF_ERROR(require_world(d, where));
    PRISM_ASSIGN_OR_RETURN(Token n, string_arg(tokens, d, "name"));
    PRISM_ASSIGN_OR_RETURN(ParameterList params, ParameterList::parse(tokens));
    PRISM_ASSIGN_OR_RETURN(std::optional<std::string> type, params.find_string("type"));
    if (!type)
      return location_error(where, absl::StrCat("'", name, "' needs a 'string type' parameter"));
    TypeName type_name{*type, params.find("type")->where};
    params.set_policy(&features_, absl::StrCat(name, " \"", n.text, "\""));
    auto& names = is_material ? named_materials_ : named_media_;
    if (auto it = names.find(n.text); it != names.end()) {
      const SourceLocation& first = is_material
                                        ? scene_.materials[static_cast<size_t>(it->second)].where
                                        : scene_.media[static_cast<size_t>(it->second)].where;
      return location_error(tokens.location(n),
                            absl::StrCat(is_material ? "named material \"" : "medium \"", n.text,
                                         "\" redefined (first at ", first.to_string(), ")"));
    }
    if (is_material) {
      PRISM_ASSIGN_OR_RETURN(MaterialKind kind, make_material(type_name, params, ctx_));
      names[n.text] = static_cast<int>(scene_.materials.size());
      scene_.materials.push_back(Material{n.text, std::move(kind), where});
    } else {
      PRISM_ASSIGN_OR_RETURN(Medium medium, make_medium(type_name, params, ctx_));
      medium.name = n.text;
      medium.where = where;
      names[n.text] = static_cast<int>(scene_.media.size());
      scene_.media.push_back(std::move(medium));
    }
  } else if (name == "NamedMaterial") {
    PRISM_RETURN_IF_ERROR(require_world(d, where));
    PRISM_ASSIGN_OR_RETURN(Token n, string_arg(tokens, d, "material name"));
    auto it = named_materials_.find(n.text);
    if (it != named_materials_.end()) {
      state_.material = it->second;
    } else {
      // Defined later, maybe: pbrt-v4 resolves material names when it builds the scene. Until
      // the end the shapes carry -2 - (its index in pending_materials_).
      auto pending = std::find_if(pending_materials_.begin(), pending_materials_.end(),
                                  [&](const auto& p) { return p.first == n.text; });
      if (pending == pending_materials_.end()) {
        pending_materials_.emplace_back(n.text, tokens.location(n));
        pending = pending_materials_.end() - 1;
      }
      state_.material = -2 - static_cast<int>(pending - pending_materials_.begin());
    }
  } else if (name == "MediumInterface") {
    PRISM_ASSIGN_OR_RETURN(Token inside, string_arg(tokens, d, "medium name"));
    Token outside = inside;
    PRISM_ASSIGN_OR_RETURN(Token next, tokens.peek());
    if (next.kind == Token::Kind::kString) {
      PRISM_ASSIGN_OR_RETURN(outside, tokens.next());
    }
    PRISM_ASSIGN_OR_RETURN(state_.inside_medium, medium_index(inside, tokens.location(inside)));
    PRISM_ASSIGN_OR_RETURN(state_.outside_medium, medium_index(outside, tokens.location(outside)));
  } else if (name == "LightSource") {
    PRISM_RETURN_IF_ERROR(require_world(d, where));
    if (current_object_)
      PRISM_RETURN_IF_ERROR(
          features_.refuse("light source inside ObjectBegin", where,
                           "light sources inside ObjectBegin/ObjectEnd are not supported",
                           "the scene without the light"));
    PRISM_ASSIGN_OR_RETURN(auto td, typed_directive());
    if (state_.ctm.moves())
      features_.supported("moving LightSource", where,
                          "pbrt-v4 places a light by its StartTime transform; so does Prism");
    PRISM_ASSIGN_OR_RETURN(std::optional<Light> light,
                           make_light(td.first, td.second, state_.ctm.start, ctx_));
    if (current_object_) light.reset();
    if (light) {
      light->medium = state_.outside_medium;
      light->where = where;
      scene_.lights.push_back(std::move(*light));
    }
  } else if (name == "AreaLightSource") {
    PRISM_RETURN_IF_ERROR(require_world(d, where));
    PRISM_ASSIGN_OR_RETURN(auto td, typed_directive());
    PRISM_ASSIGN_OR_RETURN(std::optional<AreaLight> area,
                           make_area_light(td.first, td.second, ctx_));
    if (area) area->where = where;
    state_.area_light = std::move(area);
  } else if (name == "Include" || name == "Import") {
    PRISM_ASSIGN_OR_RETURN(Token f, string_arg(tokens, d, "file name"));
    SourceLocation at = tokens.location(f);
    PRISM_ASSIGN_OR_RETURN(std::string relpath, resolve(f.text, at));
    if (std::find(open_files_.begin(), open_files_.end(), relpath) != open_files_.end()) {
      std::string chain;
      for (auto it = std::find(open_files_.begin(), open_files_.end(), relpath);
           it != open_files_.end(); ++it) {
        absl::StrAppend(&chain, *it, " -> ");
      }
      return location_error(
          where, absl::StrCat("'", name, "' of \"", relpath, "\" makes a cycle: ", chain, relpath));
    }
    if (depth + 1 > kMaxIncludeDepth)
      return location_error(
          where, absl::StrCat("'", name, "' nesting is deeper than ", kMaxIncludeDepth, " levels"));
    PRISM_ASSIGN_OR_RETURN(std::string text, read(relpath, options_.max_scene_file_bytes, at));
    record_file(relpath);
    open_files_.push_back(relpath);
    PRISM_RETURN_IF_ERROR(parse_file(text, relpath, depth + 1));
    open_files_.pop_back();
  } else if (name == "ObjectBegin") {
    PRISM_RETURN_IF_ERROR(require_world(d, where));
    PRISM_ASSIGN_OR_RETURN(Token n, string_arg(tokens, d, "object name"));
    if (current_object_)
      return location_error(
          where, absl::StrCat("'ObjectBegin' inside the definition of \"", *current_object_, "\""));
    if (auto it = objects_.find(n.text); it != objects_.end())
      return location_error(tokens.location(n),
                            absl::StrCat("object \"", n.text, "\" redefined (first at ",
                                         it->second.where.to_string(), ")"));
    scopes_.push_back(Scope{ScopeKind::kObject, state_, where});
    objects_[n.text].where = where;
    current_object_ = n.text;
  } else if (name == "ObjectEnd") {
    PRISM_RETURN_IF_ERROR(require_world(d, where));
    if (!current_object_ || scopes_.empty() || scopes_.back().kind != ScopeKind::kObject)
      return location_error(where, "unmatched 'ObjectEnd'");
    state_ = scopes_.back().saved;
    scopes_.pop_back();
    current_object_.reset();
  } else if (name == "ObjectInstance") {
    PRISM_RETURN_IF_ERROR(require_world(d, where));
    PRISM_ASSIGN_OR_RETURN(Token n, string_arg(tokens, d, "object name"));
    if (current_object_)
      return location_error(where, "'ObjectInstance' inside ObjectBegin/ObjectEnd");
    auto it = objects_.find(n.text);
    if (it == objects_.end()) {
      // pbrt-v4 resolves instances after the whole scene is read: an object may be defined
      // after its first instance.
      PRISM_RETURN_IF_ERROR(refuse_motion("ObjectInstance", where));
      pending_instances_.push_back({n.text, state_.ctm.start, where, tokens.location(n)});
      return absl::OkStatus();
    }
    PRISM_RETURN_IF_ERROR(refuse_motion("ObjectInstance", where));
    PRISM_RETURN_IF_ERROR(instantiate(it->second, state_.ctm.start, where));
  } else if (name == "Texture") {
    PRISM_RETURN_IF_ERROR(require_world(d, where));
    PRISM_ASSIGN_OR_RETURN(Token n, string_arg(tokens, d, "texture name"));
    PRISM_ASSIGN_OR_RETURN(Token kind, string_arg(tokens, d, "texture type"));
    if (kind.text != "spectrum" && kind.text != "float")
      return location_error(tokens.location(kind),
                            absl::StrCat("texture type \"", kind.text,
                                         "\" is not supported (supported: float, spectrum)"));
    const bool spectrum = kind.text == "spectrum";
    PRISM_ASSIGN_OR_RETURN(auto td, typed_directive());
    if (state_.ctm.moves())
      features_.supported("moving Texture", where,
                          "pbrt-v4 maps a texture by its StartTime transform; so does Prism");
    reading_texture_ = true;
    absl::StatusOr<TextureKind> texture =
        make_texture(td.first, spectrum, td.second, state_.ctm.start, ctx_);
    reading_texture_ = false;
    if (!texture.ok()) return texture.status();
    auto& names = spectrum ? spectrum_textures_ : float_textures_;
    if (auto it = names.find(n.text); it != names.end())
      return location_error(
          tokens.location(n),
          absl::StrCat(kind.text, " texture \"", n.text, "\" redefined (first at ",
                       scene_.textures[static_cast<size_t>(it->second)].where.to_string(), ")"));
    Texture defined{n.text, spectrum, *std::move(texture), where};
    if (auto pending = pending_textures_.find({n.text, spectrum});
        pending != pending_textures_.end()) {
      names[n.text] = pending->second.index;
      scene_.textures[static_cast<size_t>(pending->second.index)] = std::move(defined);
      pending_textures_.erase(pending);
    } else {
      names[n.text] = static_cast<int>(scene_.textures.size());
      scene_.textures.push_back(std::move(defined));
    }
  } else if (name == "Accelerator") {
    PRISM_RETURN_IF_ERROR(require_options(d, where));
    PRISM_ASSIGN_OR_RETURN(auto td, typed_directive());
    if (td.first.name != "bvh" && td.first.name != "kdtree") {
      return location_error(td.first.where,
                            absl::StrCat("unknown accelerator \"", td.first.name,
                                         "\" (pbrt-v4's: bvh, kdtree; Prism always builds "
                                         "Embree's BVH)"));
    }
    td.second.mark_all_used();
    features_.ignored(absl::StrCat("Accelerator \"", td.first.name, "\""), where,
                      "Prism always builds Embree's BVH; the image is the same");
  } else if (name == "TransformTimes") {
    PRISM_ASSIGN_OR_RETURN(std::vector<double> v, numbers(tokens, 2, d, false));
    (void)v;
    features_.ignored(
        "TransformTimes", where,
        "the shutter times only matter to moving shapes and cameras, which are refused");
  } else if (name == "WorldEnd") {
    features_.ignored("WorldEnd", where, "a pbrt-v3 directive; the scene ends with its file");
  } else if (name == "Attribute") {
    PRISM_RETURN_IF_ERROR(skip_directive(
        tokens, d, where,
        "directive 'Attribute' (default parameters for later shapes, lights, materials, media "
        "or textures) is not supported by Prism"));
  } else if (name == "MakeNamedCamera") {
    PRISM_RETURN_IF_ERROR(
        skip_directive(tokens, d, where, "directive 'MakeNamedCamera' is not supported by Prism"));
  } else {
    PRISM_RETURN_IF_ERROR(
        skip_directive(tokens, d, where, absl::StrCat("unknown directive '", name, "'")));
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<SceneDescription> parse_scene(std::string_view text, const std::string& file_relpath,
                                             const LoadOptions& options, const SceneFiles& files) {
  SceneParser parser(options, files);
  return parser.run(text, file_relpath);
}

absl::StatusOr<SceneDescription> parse_scene_string(
    std::string_view text, const std::string& name, const LoadOptions& options,
    const std::map<std::string, std::string>& files) {
  SceneFiles access;
  auto lookup = [&files](const std::string& relpath) -> absl::StatusOr<const std::string*> {
    auto it = files.find(relpath);
    if (it == files.end())
      return absl::NotFoundError(absl::StrCat("file \"", relpath, "\" does not exist"));
    return &it->second;
  };
  access.read = [lookup](const std::string& relpath,
                         std::uint64_t max_bytes) -> absl::StatusOr<std::string> {
    PRISM_ASSIGN_OR_RETURN(const std::string* text, lookup(relpath));
    if (text->size() > max_bytes)
      return absl::ResourceExhaustedError(
          absl::StrCat("file \"", relpath, "\" is larger than ", max_bytes, " bytes"));
    return *text;
  };
  access.load_mesh = [lookup](const std::string& relpath, MeshFormat format,
                              const MeshLimits& limits) -> absl::StatusOr<TriangleMeshData> {
    PRISM_ASSIGN_OR_RETURN(const std::string* bytes, lookup(relpath));
    if (bytes->size() > limits.max_file_bytes)
      return absl::ResourceExhaustedError(
          absl::StrCat("file \"", relpath, "\" is larger than ", limits.max_file_bytes, " bytes"));
    return format == MeshFormat::kPly ? parse_ply(*bytes, relpath, limits)
                                      : parse_obj(*bytes, relpath, limits);
  };
  return parse_scene(text, name, options, access);
}

}  // namespace prism::scene
