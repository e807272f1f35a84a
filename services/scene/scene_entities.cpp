#include "services/scene/scene_entities.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <map>
#include <string_view>
#include <utility>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "services/base/status.h"
#include "services/scene/loop_subdivision.h"

namespace prism::scene {
namespace {

// `Material "coateddiffuse"`: the feature a directive's type is, in reports, named by the
// directive as the scene writes it.
std::string type_feature(std::string_view what, const TypeName& type) {
  static constexpr std::pair<std::string_view, std::string_view> kDirective[] = {
      {"camera", "Camera"},
      {"film", "Film"},
      {"sampler", "Sampler"},
      {"integrator", "Integrator"},
      {"pixel filter", "PixelFilter"},
      {"material", "Material"},
      {"spectrum texture", "Texture"},
      {"float texture", "Texture"},
      {"light", "LightSource"},
      {"area light", "AreaLightSource"},
      {"medium", "MakeNamedMedium"},
      {"shape", "Shape"}};
  for (const auto& [w, directive] : kDirective)
    if (w == what) return absl::StrCat(absl_view(directive), " \"", type.name, "\"");
  return absl::StrCat(absl_view(what), " \"", type.name, "\"");
}

void note_supported(const ParameterList& params, const char* what, const TypeName& type,
                    std::string_view note = {}) {
  if (params.features() != nullptr)
    params.features()->supported(type_feature(what, type), type.where, note);
}

// A refusal at `where`: the error, or (the load allows unsupported input) OK once the
// substitution is recorded; the caller then builds the substitution.
absl::Status refuse_at(const ParameterList& params, const std::string& feature,
                       const SourceLocation& where, const std::string& message,
                       std::string_view substitution) {
  if (params.features() == nullptr) return location_error(where, message);
  return params.features()->refuse(feature, where, message, substitution);
}

// pbrt-v4's type names per kind of entity (`what` as in unsupported_type).
const std::vector<const char*>* pbrt_type_names(std::string_view what) {
  static const std::map<std::string_view, std::vector<const char*>> kPbrtTypes = {
      {"camera", {"orthographic", "perspective", "realistic", "spherical"}},
      {"film", {"gbuffer", "rgb", "spectral"}},
      {"integrator",
       {"ambientocclusion", "aov", "bdpt", "function", "lightpath", "mlt", "path", "randomwalk",
        "simplepath", "simplevolpath", "sppm", "volpath"}},
      {"sampler",
       {"halton", "independent", "paddedsobol", "pmj02bn", "sobol", "stratified", "zsobol"}},
      {"pixel filter", {"box", "gaussian", "mitchell", "sinc", "triangle"}},
      {"material",
       {"coatedconductor", "coateddiffuse", "conductor", "dielectric", "diffuse",
        "diffusetransmission", "hair", "interface", "measured", "mix", "subsurface",
        "thindielectric"}},
      {"light", {"distant", "goniometric", "infinite", "point", "projection", "spot"}},
      {"area light", {"diffuse"}},
      {"medium", {"cloud", "homogeneous", "nanovdb", "rgbgrid", "uniformgrid"}},
      {"shape",
       {"bilinearmesh", "curve", "cylinder", "disk", "loopsubdiv", "plymesh", "sphere",
        "trianglemesh"}},
      {"float texture",
       {"bilerp", "checkerboard", "constant", "directionmix", "dots", "fbm", "imagemap", "mix",
        "ptex", "scale", "windy", "wrinkled"}},
      {"spectrum texture",
       {"bilerp", "checkerboard", "constant", "directionmix", "dots", "fbm", "imagemap", "marble",
        "mix", "ptex", "scale", "windy", "wrinkled"}},
  };
  auto it = kPbrtTypes.find(what);
  return it == kPbrtTypes.end() ? nullptr : &it->second;
}

bool is_pbrt_type(std::string_view what, const std::string& name) {
  const std::vector<const char*>* names = pbrt_type_names(what);
  return names != nullptr &&
         std::any_of(names->begin(), names->end(), [&](const char* n) { return name == n; });
}

// A type name pbrt-v4 does not know either is a mistake (pbrt-v4 stops on it), not a feature to
// substitute under --allow-unsupported: the error lists pbrt-v4's names and Prism's.
absl::Status unknown_type(const TypeName& type, const char* what,
                          std::initializer_list<const char*> prism) {
  return location_error(type.where,
                        absl::StrCat("unknown ", what, " type \"", type.name,
                                     "\" (pbrt-v4's: ", absl::StrJoin(*pbrt_type_names(what), ", "),
                                     "; Prism renders ", absl::StrJoin(prism, ", "), ")"));
}

// An unknown type: refused, or substituted as a whole (its parameters go with it).
absl::Status unsupported_type(const ParameterList& params, const TypeName& type, const char* what,
                              std::initializer_list<const char*> supported,
                              std::string_view substitution) {
  if (pbrt_type_names(what) != nullptr && !is_pbrt_type(what, type.name)) {
    return unknown_type(type, what, supported);
  }
  PRISM_RETURN_IF_ERROR(
      refuse_at(params, type_feature(what, type), type.where,
                absl::StrCat("unsupported ", what, " type \"", type.name,
                             "\" (supported: ", absl::StrJoin(supported, ", "), ")"),
                substitution));
  params.mark_all_used();
  return absl::OkStatus();
}

// An error at the parameter's declaration.
absl::Status param_error(const ParameterList& params, const std::string& name,
                         const std::string& message) {
  const Parameter* p = params.find(name);
  return location_error(p->where, absl::StrCat("'", written_type(*p), " ", name, "' ", message));
}

absl::Status check_range(const ParameterList& params, const std::string& name, double value,
                         double lo, double hi, const std::string& range_text) {
  if (!params.has(name) || (value >= lo && value <= hi)) return absl::OkStatus();
  // Bounds far out guard the float arithmetic, not the meaning: say which one was crossed
  // ("must be > 0, got 1e+39" told a user their positive radius was not positive).
  if (value > hi && hi >= 1e30) {
    return param_error(
        params, name,
        absl::StrCat("must be at most ", hi, " (Prism computes in single precision), got ", value));
  }
  if (value > 0 && value < lo && lo <= 1e-9) {
    return param_error(params, name,
                       absl::StrCat("must be at least ", lo,
                                    " (Prism computes in single precision), got ", value));
  }
  return param_error(params, name, absl::StrCat("must be ", range_text, ", got ", value));
}

// A value Prism does not render (a partial sphere's zmin): the error at the parameter, or
// (allowing unsupported input) OK with `substitution` recorded.
absl::Status refuse_value(const ParameterList& params, const std::string& name,
                          const std::string& message, std::string_view substitution) {
  const Parameter* p = params.find(name);
  return refuse_at(params, params.feature(*p), p->where,
                   absl::StrCat("'", written_type(*p), " ", name, "' ", message), substitution);
}

absl::StatusOr<int> texture_reference(const Parameter& p, bool spectrum, const EntityContext& ctx);

// A float slot that may name a float texture: sets *value or *texture when the parameter is
// given, leaves them as they are otherwise.
absl::Status read_float_slot(const ParameterList& params, const std::string& name,
                             const EntityContext& ctx, double* value, int* texture) {
  const Parameter* p = params.find(name);
  if (p == nullptr) return absl::OkStatus();
  if (p->type == ParamType::kTexture) {
    PRISM_ASSIGN_OR_RETURN(*texture, texture_reference(*p, false, ctx));
    return absl::OkStatus();
  }
  PRISM_ASSIGN_OR_RETURN(*value, params.get_float(name, *value));
  *texture = -1;
  return absl::OkStatus();
}

absl::StatusOr<Roughness> read_roughness(const ParameterList& params, const EntityContext& ctx,
                                         const std::string& prefix = "") {
  const std::string rough_name = absl::StrCat(prefix, "roughness");
  const std::string u_name = absl::StrCat(prefix, "uroughness");
  const std::string v_name = absl::StrCat(prefix, "vroughness");
  Roughness r;
  double rough = 0;
  int rough_texture = -1;
  PRISM_RETURN_IF_ERROR(read_float_slot(params, rough_name, ctx, &rough, &rough_texture));
  r.u = r.v = rough;
  r.u_texture = r.v_texture = rough_texture;
  PRISM_RETURN_IF_ERROR(read_float_slot(params, u_name, ctx, &r.u, &r.u_texture));
  PRISM_RETURN_IF_ERROR(read_float_slot(params, v_name, ctx, &r.v, &r.v_texture));
  PRISM_ASSIGN_OR_RETURN(r.remap, params.get_bool("remaproughness", true));
  for (const std::string& name : {rough_name, u_name, v_name}) {
    const Parameter* p = params.find(name);
    if (p == nullptr || p->type == ParamType::kTexture) continue;
    PRISM_ASSIGN_OR_RETURN(double v, params.get_float(name, 0.0));
    PRISM_RETURN_IF_ERROR(check_range(params, name, v, 0.0, 1e30, ">= 0"));
  }
  return r;
}

absl::Status refuse_common_material_params(const ParameterList& params) {
  PRISM_RETURN_IF_ERROR(
      params.refuse("displacement", "displacement is not supported", "the undisplaced surface"));
  PRISM_RETURN_IF_ERROR(params.refuse("normalmap", "normal maps are not supported",
                                      "the surface's own shading normals"));
  return absl::OkStatus();
}

absl::StatusOr<IorParam> ior_parameter(const ParameterList& params, const std::string& name,
                                       const EntityContext& ctx);

absl::StatusOr<IorParam> read_dielectric_eta(const ParameterList& params,
                                             const EntityContext& ctx) {
  int given = params.has("eta") + params.has("cauchy") + params.has("sellmeier");
  if (given > 1) {
    const char* second = params.has("sellmeier") ? "sellmeier" : "cauchy";
    return param_error(
        params, second,
        "conflicts with another index of refraction (give one of eta, cauchy, sellmeier)");
  }
  if (params.has("cauchy")) {
    PRISM_ASSIGN_OR_RETURN(std::vector<double> c, params.get_floats("cauchy"));
    if (c.size() < 2 || c.size() > 4)
      return param_error(params, "cauchy",
                         absl::StrCat("needs 2 to 4 coefficients [A B C D], got ", c.size()));
    if (!(c[0] > 0)) return param_error(params, "cauchy", "needs A > 0");
    return IorCauchy{c};
  }
  if (params.has("sellmeier")) {
    PRISM_ASSIGN_OR_RETURN(std::vector<double> c, params.get_floats("sellmeier"));
    if (c.size() != 6)
      return param_error(
          params, "sellmeier",
          absl::StrCat("needs 6 coefficients [B1 B2 B3 C1 C2 C3] (C in um^2), got ", c.size()));
    IorSellmeier s;
    for (int i = 0; i < 3; ++i) {
      s.b[i] = c[i];
      s.c[i] = c[3 + i];
      if (s.c[i] < 0) return param_error(params, "sellmeier", "needs C1..C3 >= 0");
    }
    return s;
  }
  return ior_parameter(params, "eta", ctx);
}

// An index of refraction given as a float or a spectrum (a named IOR, a table or a file);
// 1.5 when absent.
absl::StatusOr<IorParam> ior_parameter(const ParameterList& params, const std::string& name,
                                       const EntityContext& ctx) {
  const Parameter* p = params.find(name);
  if (p == nullptr) return IorConstant{1.5};
  if (p->type == ParamType::kRgb)
    return param_error(params, name, "cannot be an rgb value; use a float or a spectrum");
  PRISM_ASSIGN_OR_RETURN(std::optional<SpectrumParam> found,
                         params.find_spectrum(name, SpectrumRole::kIor, ctx.spectra));
  SpectrumParam s = found.value_or(SpectrumConstant{1.5});
  if (const auto* c = std::get_if<SpectrumConstant>(&s)) {
    if (!(c->value > 0)) return param_error(params, name, "must be > 0");
    return IorConstant{c->value};
  }
  if (const auto* n = std::get_if<SpectrumNamed>(&s)) return IorNamed{n->name};
  if (auto* t = std::get_if<SpectrumTabulated>(&s)) {
    for (double v : t->values)
      if (!(v > 0)) return param_error(params, name, "needs values > 0");
    return IorTabulated{std::move(*t)};
  }
  return param_error(params, name, "must be a float or a spectrum (named, table or file)");
}

absl::StatusOr<SpectrumParam> spectrum_or(const ParameterList& params, const std::string& name,
                                          SpectrumRole role, const EntityContext& ctx,
                                          SpectrumParam fallback) {
  PRISM_ASSIGN_OR_RETURN(std::optional<SpectrumParam> s,
                         params.find_spectrum(name, role, ctx.spectra));
  if (s) return std::move(*s);
  return fallback;
}

// `texture name`: the index of a texture of the wanted kind (EntityContext::find_texture).
absl::StatusOr<int> texture_reference(const Parameter& p, bool spectrum, const EntityContext& ctx) {
  p.used = true;
  if (p.strings.size() != 1)
    return location_error(p.where, absl::StrCat("'texture ", p.name, "' takes one texture name"));
  std::optional<int> index =
      ctx.find_texture ? ctx.find_texture(p.strings[0], spectrum, p.where) : std::nullopt;
  if (!index) {
    const bool other_kind = ctx.find_texture && ctx.find_texture(p.strings[0], !spectrum, p.where);
    if (other_kind) {
      return location_error(
          p.where, absl::StrCat("texture \"", p.strings[0], "\" is a ",
                                spectrum ? "float" : "spectrum", " texture; 'texture ", p.name,
                                "' needs a ", spectrum ? "spectrum" : "float", " texture"));
    }
    return location_error(p.where, absl::StrCat(spectrum ? "spectrum" : "float", " texture \"",
                                                p.strings[0], "\" is not defined"));
  }
  return *index;
}

// A material's spectrum slot: a spectrum, or `texture name` naming a spectrum texture.
absl::Status read_spectrum_slot(const ParameterList& params, const std::string& name,
                                SpectrumRole role, const EntityContext& ctx, SpectrumParam* value,
                                int* texture) {
  if (const Parameter* p = params.find(name); p != nullptr && p->type == ParamType::kTexture) {
    PRISM_ASSIGN_OR_RETURN(*texture, texture_reference(*p, true, ctx));
    return absl::OkStatus();
  }
  PRISM_ASSIGN_OR_RETURN(std::optional<SpectrumParam> s,
                         params.find_spectrum(name, role, ctx.spectra));
  if (s) *value = std::move(*s);
  return absl::OkStatus();
}

// A texture's own parameter: another texture or a constant. Spectrum constants are read as
// unbounded (a texture may be scaled down later); the worker uplifts RGB as an albedo where it
// is one.
absl::StatusOr<TextureInput> texture_input(const ParameterList& params, const std::string& name,
                                           bool spectrum, double fallback,
                                           const EntityContext& ctx) {
  TextureInput in;
  in.value = fallback;
  in.spectrum = SpectrumConstant{fallback};
  const Parameter* p = params.find(name);
  if (p == nullptr) return in;
  if (p->type == ParamType::kTexture) {
    PRISM_ASSIGN_OR_RETURN(in.texture, texture_reference(*p, spectrum, ctx));
    return in;
  }
  if (spectrum) {
    PRISM_ASSIGN_OR_RETURN(std::optional<SpectrumParam> s,
                           params.find_spectrum(name, SpectrumRole::kUnbounded, ctx.spectra));
    in.spectrum = std::move(*s);
  } else {
    PRISM_ASSIGN_OR_RETURN(in.value, params.get_float(name, fallback));
  }
  return in;
}

absl::StatusOr<UvMapping> read_uv_mapping(const ParameterList& params) {
  PRISM_ASSIGN_OR_RETURN(std::string mapping, params.get_string("mapping", "uv"));
  if (mapping != "uv")
    PRISM_RETURN_IF_ERROR(refuse_value(
        params, "mapping", absl::StrCat("\"", mapping, "\" is not supported (supported: uv)"),
        "the uv mapping"));
  UvMapping m;
  PRISM_ASSIGN_OR_RETURN(m.su, params.get_float("uscale", 1.0));
  PRISM_ASSIGN_OR_RETURN(m.sv, params.get_float("vscale", 1.0));
  PRISM_ASSIGN_OR_RETURN(m.du, params.get_float("udelta", 0.0));
  PRISM_ASSIGN_OR_RETURN(m.dv, params.get_float("vdelta", 0.0));
  return m;
}

double srgb_to_linear(double c) {
  return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4);
}

// A light's image (`string filename`), linear: 8-bit files decoded as sRGB, as pbrt-v4 reads
// them. `square_for` names what needs a square image ("" when any shape will do).
struct LightImage {
  std::shared_ptr<const TextureImage> image;
  std::string relpath;
};
absl::StatusOr<LightImage> read_light_image(const ParameterList& params, const TypeName& type,
                                            const EntityContext& ctx, const std::string& filename,
                                            const char* square_for) {
  if (!ctx.load_image) return location_error(type.where, "images cannot be read here");
  PRISM_ASSIGN_OR_RETURN(EntityContext::LoadedImage loaded,
                         ctx.load_image(filename, params.find("filename")->where));
  if (*square_for != '\0' && loaded.image->width != loaded.image->height)
    return param_error(params, "filename",
                       absl::StrCat("\"", loaded.relpath, "\" is ", loaded.image->width, "x",
                                    loaded.image->height, "; ", square_for, " must be square"));
  LightImage out{loaded.image, loaded.relpath};
  if (loaded.eight_bit) {
    auto decoded = std::make_shared<TextureImage>(*loaded.image);
    for (float& v : decoded->values) v = float(srgb_to_linear(double(v)));
    out.image = std::move(decoded);
  }
  return out;
}

absl::StatusOr<LayerSpec> read_layer(const ParameterList& params, const EntityContext& ctx) {
  LayerSpec l;
  PRISM_RETURN_IF_ERROR(
      read_float_slot(params, "thickness", ctx, &l.thickness, &l.thickness_texture));
  if (l.thickness_texture < 0)
    PRISM_RETURN_IF_ERROR(check_range(params, "thickness", l.thickness, 1e-30, 1e30, "> 0"));
  PRISM_RETURN_IF_ERROR(read_float_slot(params, "g", ctx, &l.g, &l.g_texture));
  if (l.g_texture < 0)
    PRISM_RETURN_IF_ERROR(check_range(params, "g", l.g, -0.99, 0.99, "in [-0.99, 0.99]"));
  PRISM_ASSIGN_OR_RETURN(l.max_depth, params.get_int("maxdepth", 10));
  PRISM_RETURN_IF_ERROR(check_range(params, "maxdepth", l.max_depth, 1, 1000, "in [1, 1000]"));
  PRISM_ASSIGN_OR_RETURN(l.samples, params.get_int("nsamples", 1));
  PRISM_RETURN_IF_ERROR(check_range(params, "nsamples", l.samples, 1, 1000, "in [1, 1000]"));
  PRISM_RETURN_IF_ERROR(read_spectrum_slot(params, "albedo", SpectrumRole::kReflectance, ctx,
                                           &l.albedo, &l.albedo_texture));
  return l;
}

// A coat's index: a float or a spectrum (pbrt-v4 evaluates a varying one at the hero
// wavelength and terminates the others, as Prism does). pbrt-v4 does not texture it: its
// coated materials read `eta` as a float or a spectrum only, so a `texture eta` is an unused
// parameter there and pbrt-v4 stops; Prism refuses it by name.
absl::StatusOr<IorParam> read_coat_eta(const ParameterList& params, const std::string& name,
                                       const EntityContext& ctx) {
  const Parameter* p = params.find(name);
  if (p != nullptr && p->type == ParamType::kTexture) {
    PRISM_RETURN_IF_ERROR(
        refuse_at(params, params.feature(*p), p->where,
                  absl::StrCat("'texture ", name, "': a coat's ", name,
                               " is a float or a spectrum, not a texture (pbrt-v4 rejects it too, "
                               "as an unused parameter)"),
                  absl::StrCat("the default ", name, " 1.5")));
    p->used = true;
    return IorConstant{1.5};
  }
  return ior_parameter(params, name, ctx);
}

// An image infinite light's `point3 portal`: four corners of a rectangle, in order around it,
// in world space.
absl::StatusOr<std::optional<std::array<Vec3, 4>>> read_portal(const ParameterList& params) {
  if (!params.has("portal")) return std::nullopt;
  PRISM_ASSIGN_OR_RETURN(std::vector<Vec3> p, params.get_triples("portal", ParamType::kPoint3));
  if (p.size() != 4) {
    return param_error(params, "portal",
                       absl::StrCat("needs 4 points (the corners of a rectangle), got ", p.size()));
  }
  auto sub = [](const Vec3& a, const Vec3& b) {
    return Vec3{a[0] - b[0], a[1] - b[1], a[2] - b[2]};
  };
  auto len = [](const Vec3& v) { return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); };
  const Vec3 e01 = sub(p[1], p[0]), e03 = sub(p[3], p[0]);
  const double l01 = len(e01), l03 = len(e03);
  if (!(l01 > 0) || !(l03 > 0) || !std::isfinite(l01) || !std::isfinite(l03))
    return param_error(params, "portal", "has coincident corners");
  // A rectangle: right angle at p0 and p2 = p1 + p3 − p0 (pbrt-v4 checks the same to 1e-3).
  const double cos0 = (e01[0] * e03[0] + e01[1] * e03[1] + e01[2] * e03[2]) / (l01 * l03);
  const Vec3 gap = sub(p[2], Vec3{p[1][0] + e03[0], p[1][1] + e03[1], p[1][2] + e03[2]});
  if (std::abs(cos0) > 1e-3 || len(gap) > 1e-3 * std::max(l01, l03)) {
    return param_error(params, "portal",
                       "is not a rectangle (its corners p0, p1, p2, p3 must go around one, with "
                       "p2 = p1 + p3 - p0 and a right angle at p0)");
  }
  return std::array<Vec3, 4>{p[0], p[1], p[2], p[3]};
}

absl::StatusOr<std::optional<double>> positive_optional(const ParameterList& params,
                                                        const std::string& name) {
  PRISM_ASSIGN_OR_RETURN(std::optional<double> v, params.find_float(name));
  if (v && !(*v > 0)) return param_error(params, name, "must be > 0");
  return v;
}

Vec3 normalize(const Vec3& v) {
  double l = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  return {v[0] / l, v[1] / l, v[2] / l};
}

Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}

// A rotation taking light space +z to `dir` (any completion of the frame: the spot is symmetric).
Transform frame_from_z(const Vec3& dir) {
  Vec3 z = normalize(dir);
  Vec3 helper = std::abs(z[0]) > 0.9 ? Vec3{0, 1, 0} : Vec3{1, 0, 0};
  Vec3 x = normalize(cross(helper, z));
  Vec3 y = cross(z, x);
  Matrix4 m{};
  for (int i = 0; i < 3; ++i) {
    m[i][0] = x[i];
    m[i][1] = y[i];
    m[i][2] = z[i];
  }
  m[3][3] = 1.0;
  return *Transform::from_matrix(m);
}

absl::StatusOr<std::shared_ptr<TriangleMeshData>> inline_mesh(const ParameterList& params,
                                                              bool bilinear, const TypeName& type,
                                                              const EntityContext& ctx) {
  const size_t corners = bilinear ? 4 : 3;
  PRISM_ASSIGN_OR_RETURN(std::vector<Vec3> p, params.get_triples("P", ParamType::kPoint3));
  PRISM_ASSIGN_OR_RETURN(std::vector<std::int64_t> indices, params.get_ints("indices"));
  PRISM_ASSIGN_OR_RETURN(std::vector<Vec3> n, params.get_triples("N", ParamType::kNormal3));
  PRISM_ASSIGN_OR_RETURN(auto uv, params.get_point2s("uv"));
  if (p.empty())
    return location_error(type.where, absl::StrCat("\"", type.name, "\" needs 'point3 P'"));
  if (indices.empty()) {
    if (p.size() != corners)
      return location_error(
          type.where,
          absl::StrCat("\"", type.name, "\" needs 'integer indices' (only a single ",
                       bilinear ? "patch of 4" : "triangle of 3", " vertices may omit them)"));
    for (size_t i = 0; i < corners; ++i) indices.push_back(static_cast<std::int64_t>(i));
  }
  if (indices.size() % corners != 0)
    return param_error(
        params, "indices",
        absl::StrCat("needs a multiple of ", corners, " values, got ", indices.size()));
  for (std::int64_t i : indices)
    if (i < 0 || static_cast<size_t>(i) >= p.size())
      return param_error(
          params, "indices",
          absl::StrCat("refers to vertex ", i, " but 'P' has ", p.size(), " vertices"));
  if (!n.empty() && n.size() != p.size())
    return param_error(params, "N",
                       absl::StrCat("has ", n.size(), " normals for ", p.size(), " vertices"));
  if (!uv.empty() && uv.size() != p.size())
    return param_error(params, "uv",
                       absl::StrCat("has ", uv.size(), " uvs for ", p.size(), " vertices"));
  size_t triangles = indices.size() / corners * (bilinear ? 2 : 1);
  if (triangles > ctx.mesh_limits.max_triangles)
    return absl::ResourceExhaustedError(
        absl::StrCat(type.where.to_string(), ": \"", type.name, "\" has ", triangles,
                     " triangles, more than the limit of ", ctx.mesh_limits.max_triangles));
  auto mesh = std::make_shared<TriangleMeshData>();
  mesh->positions.reserve(p.size() + 1);
  for (const Vec3& v : p)
    mesh->positions.push_back(
        {static_cast<float>(v[0]), static_cast<float>(v[1]), static_cast<float>(v[2])});
  for (const Vec3& v : n)
    mesh->normals.push_back(
        {static_cast<float>(v[0]), static_cast<float>(v[1]), static_cast<float>(v[2])});
  for (const auto& t : uv)
    mesh->uvs.push_back({static_cast<float>(t[0]), static_cast<float>(t[1])});
  auto idx = [&](size_t i) { return static_cast<std::uint32_t>(indices[i]); };
  if (bilinear && uv.empty()) {
    // A patch without uv has its own (u, v) in pbrt-v4, (0,0) (1,0) (0,1) (1,1) at its corners;
    // a triangle without uv gets (0,0) (1,0) (1,1), which the second triangle of the split does
    // not want (a seam across every textured quad). Each patch gets its own four corners with
    // the patch's uv: a parallelogram's texture is then pbrt-v4's.
    auto shared = std::move(mesh->positions);
    auto shared_normals = std::move(mesh->normals);
    mesh->positions.clear();
    mesh->normals.clear();
    mesh->positions.reserve(indices.size() + 1);  // one spare, as above (Embree reads 16 bytes)
    constexpr float kCornerUv[4][2] = {{0, 0}, {1, 0}, {0, 1}, {1, 1}};
    for (size_t i = 0; i < indices.size(); i += corners) {
      const auto base = static_cast<std::uint32_t>(mesh->positions.size());
      for (size_t c = 0; c < 4; ++c) {
        mesh->positions.push_back(shared[idx(i + c)]);
        if (!shared_normals.empty()) mesh->normals.push_back(shared_normals[idx(i + c)]);
        mesh->uvs.push_back({kCornerUv[c][0], kCornerUv[c][1]});
      }
      mesh->patches.push_back(static_cast<std::uint32_t>(mesh->triangles.size()));
      mesh->triangles.push_back({base, base + 1, base + 3});
      mesh->triangles.push_back({base, base + 3, base + 2});
    }
    if (absl::Status s = mesh->validate(); !s.ok()) return located(type.where, s);
    return mesh;
  }
  for (size_t i = 0; i < indices.size(); i += corners) {
    if (bilinear) {
      // Patch (p00, p10, p01, p11) -> (p00, p10, p11), (p00, p11, p01): same facing as the patch.
      mesh->patches.push_back(static_cast<std::uint32_t>(mesh->triangles.size()));
      mesh->triangles.push_back({idx(i), idx(i + 1), idx(i + 3)});
      mesh->triangles.push_back({idx(i), idx(i + 3), idx(i + 2)});
    } else {
      mesh->triangles.push_back({idx(i), idx(i + 1), idx(i + 2)});
    }
  }
  if (absl::Status s = mesh->validate(); !s.ok()) return located(type.where, s);
  return mesh;
}

}  // namespace

absl::StatusOr<Camera> make_camera(const TypeName& type, const ParameterList& params) {
  if (type.name != "perspective" && type.name != "orthographic" && type.name != "spherical") {
    PRISM_RETURN_IF_ERROR(unsupported_type(params, type, "camera",
                                           {"orthographic", "perspective", "spherical"},
                                           "a perspective camera with a 90 degree field of view"));
    Camera c;
    c.where = type.where;
    return c;
  }
  note_supported(params, "camera", type);
  Camera c;
  c.type = type.name;
  c.where = type.where;
  if (c.type == "spherical") {
    PRISM_ASSIGN_OR_RETURN(c.mapping, params.get_string("mapping", "equalarea"));
    if (c.mapping != "equalarea" && c.mapping != "equirectangular")
      return param_error(params, "mapping",
                         absl::StrCat("\"", c.mapping, "\": want equalarea or equirectangular"));
    PRISM_RETURN_IF_ERROR(params.refuse("lensradius", "the spherical camera has no lens"));
  }
  if (c.type == "perspective") {
    PRISM_ASSIGN_OR_RETURN(c.fov_deg, params.get_float("fov", 90.0));
    PRISM_RETURN_IF_ERROR(
        check_range(params, "fov", c.fov_deg, 1e-6, 179.999, "in (0, 180) degrees"));
  }
  PRISM_ASSIGN_OR_RETURN(c.lens_radius, params.get_float("lensradius", 0.0));
  PRISM_RETURN_IF_ERROR(check_range(params, "lensradius", c.lens_radius, 0.0, 1e30, ">= 0"));
  PRISM_ASSIGN_OR_RETURN(c.focal_distance, params.get_float("focaldistance", 1e6));
  PRISM_RETURN_IF_ERROR(check_range(params, "focaldistance", c.focal_distance, 1e-30, 1e30, "> 0"));
  PRISM_ASSIGN_OR_RETURN(c.frame_aspect_ratio, positive_optional(params, "frameaspectratio"));
  if (params.has("screenwindow")) {
    PRISM_ASSIGN_OR_RETURN(std::vector<double> w, params.get_floats("screenwindow"));
    if (w.size() != 4 || !(w[0] < w[1]) || !(w[2] < w[3]))
      return param_error(params, "screenwindow",
                         "needs 4 values xmin xmax ymin ymax with min < max");
    c.screen_window = std::array<double, 4>{w[0], w[1], w[2], w[3]};
  }
  // Nothing Prism renders moves (a moving shape, instance or camera is refused), so a static
  // scene looks the same at every time of the shutter interval; but pbrt-v4's film scales the
  // image by the interval's length, the exposure time (PixelSensor's imagingRatio =
  // exposureTime · ISO / 100). An interval of 1 (the default) is the image Prism renders.
  if (params.has("shutteropen") || params.has("shutterclose")) {
    PRISM_ASSIGN_OR_RETURN(const double open, params.get_float("shutteropen", 0.0));
    PRISM_ASSIGN_OR_RETURN(const double close, params.get_float("shutterclose", 1.0));
    const double exposure = std::abs(close - open);  // pbrt-v4 swaps a reversed interval
    const char* name = params.has("shutterclose") ? "shutterclose" : "shutteropen";
    if (!(exposure > 0)) {
      return param_error(params, name,
                         absl::StrCat("gives an empty shutter interval (", open, " to ", close,
                                      "): pbrt-v4's exposure time would be 0"));
    }
    if (exposure != 1.0) {
      PRISM_RETURN_IF_ERROR(refuse_value(
          params, name,
          absl::StrCat("makes an exposure time of ", exposure,
                       ", by which pbrt-v4 scales the image; Prism renders an exposure of 1"),
          "an exposure time of 1"));
    } else if (params.features() != nullptr) {
      const Parameter* p = params.find(name);
      params.features()->ignored(params.feature(*p), p->where,
                                 "an interval of length 1 is the exposure Prism renders, and "
                                 "nothing in a Prism scene moves");
    }
  }
  PRISM_RETURN_IF_ERROR(params.check_all_used());
  return c;
}

absl::StatusOr<Film> make_film(const TypeName& type, const ParameterList& params) {
  Film f;
  f.where = type.where;
  if (type.name == "rgb" || type.name == "spectral") {
    f.type = type.name == "rgb" ? FilmType::kRgb : FilmType::kSpectral;
    note_supported(params, "film", type);
  } else {
    if (!is_pbrt_type("film", type.name)) return unknown_type(type, "film", {"rgb", "spectral"});
    // Its common parameters (resolution, file name) still apply to the rgb film.
    PRISM_RETURN_IF_ERROR(refuse_at(
        params, type_feature("film", type), type.where,
        absl::StrCat("unsupported film type \"", type.name, "\" (supported: rgb, spectral)"),
        "an rgb film"));
    f.type = FilmType::kRgb;
  }
  PRISM_ASSIGN_OR_RETURN(f.x_resolution, params.get_int("xresolution", 1280));
  PRISM_ASSIGN_OR_RETURN(f.y_resolution, params.get_int("yresolution", 720));
  std::string range = absl::StrCat("between 1 and ", kMaxResolution);
  PRISM_RETURN_IF_ERROR(
      check_range(params, "xresolution", f.x_resolution, 1, kMaxResolution, range));
  PRISM_RETURN_IF_ERROR(
      check_range(params, "yresolution", f.y_resolution, 1, kMaxResolution, range));
  PRISM_ASSIGN_OR_RETURN(f.filename, params.get_string("filename", "pbrt.exr"));
  if (f.filename.empty()) f.filename = "pbrt.exr";  // pbrt-v4 names an empty one so too
  if (f.type == FilmType::kSpectral) {
    if (params.has("nbuckets")) {
      PRISM_ASSIGN_OR_RETURN(int bins, params.get_int("nbuckets", 16));
      PRISM_RETURN_IF_ERROR(
          check_range(params, "nbuckets", bins, kMinSpectralBins, kMaxSpectralBins,
                      absl::StrCat("between ", kMinSpectralBins, " and ", kMaxSpectralBins)));
      f.bins = bins;
    }
    PRISM_ASSIGN_OR_RETURN(double lmin, params.get_float("lambdamin", kLambdaMinNm));
    PRISM_ASSIGN_OR_RETURN(double lmax, params.get_float("lambdamax", kLambdaMaxNm));
    const std::string range = absl::StrCat(kLambdaMinNm, "-", kLambdaMaxNm, " nm");
    if (lmin != kLambdaMinNm)
      PRISM_RETURN_IF_ERROR(
          refuse_value(params, "lambdamin",
                       absl::StrCat("must be ", kLambdaMinNm, " (Prism's spectral range is ", range,
                                    "), got ", lmin),
                       absl::StrCat("bins over ", range)));
    if (lmax != kLambdaMaxNm)
      PRISM_RETURN_IF_ERROR(
          refuse_value(params, "lambdamax",
                       absl::StrCat("must be ", kLambdaMaxNm, " (Prism's spectral range is ", range,
                                    "), got ", lmax),
                       absl::StrCat("bins over ", range)));
  }
  // The sensor settings that would change pixel values are accepted only at their defaults.
  PRISM_ASSIGN_OR_RETURN(std::string sensor, params.get_string("sensor", "cie1931"));
  if (sensor != "cie1931")
    PRISM_RETURN_IF_ERROR(refuse_value(
        params, "sensor", absl::StrCat("\"", sensor, "\" is not supported (supported: cie1931)"),
        "the CIE 1931 observer"));
  PRISM_ASSIGN_OR_RETURN(double iso, params.get_float("iso", 100.0));
  if (iso != 100.0)
    PRISM_RETURN_IF_ERROR(
        refuse_value(params, "iso", "is only supported at its default, 100", "iso 100"));
  PRISM_ASSIGN_OR_RETURN(double white_balance, params.get_float("whitebalance", 0.0));
  if (white_balance != 0.0)
    PRISM_RETURN_IF_ERROR(refuse_value(params, "whitebalance", "is not supported (only 0, none)",
                                       "no white balance"));
  // The film diagonal matters only for the realistic camera.
  PRISM_ASSIGN_OR_RETURN(double diagonal, params.get_float("diagonal", 35.0));
  PRISM_RETURN_IF_ERROR(check_range(params, "diagonal", diagonal, 1e-9, 1e30, "> 0"));
  // A crop naming the whole image (pbrt-v4's default, which exporters write out) is the image
  // Prism renders; any other crop is refused.
  auto whole_image = [&](const char* name, const std::vector<double>& whole) -> absl::Status {
    const Parameter* p = params.find(name);
    if (p == nullptr) return absl::OkStatus();
    std::vector<double> v;
    if (p->type == ParamType::kInteger) {
      PRISM_ASSIGN_OR_RETURN(std::vector<std::int64_t> ints, params.get_ints(name));
      v.assign(ints.begin(), ints.end());
    } else {
      PRISM_ASSIGN_OR_RETURN(v, params.get_floats(name));
    }
    if (v.size() != 4) {
      return location_error(
          p->where, absl::StrCat("'", name, "' needs 4 values (x0 x1 y0 y1), got ", v.size()));
    }
    // pbrt-v4 orders each pair and clamps a crop window to [0, 1] (FilmBaseParameters).
    if (std::string_view(name) == "cropwindow") {
      for (int axis = 0; axis < 2; ++axis) {
        double& lo = v[std::size_t(2 * axis)];
        double& hi = v[std::size_t(2 * axis + 1)];
        if (hi < lo) std::swap(lo, hi);
        lo = std::clamp(lo, 0.0, 1.0);
        hi = std::clamp(hi, 0.0, 1.0);
      }
    }
    if (v == whole) {
      if (params.features() != nullptr)
        params.features()->ignored(params.feature(*p), p->where,
                                   "the whole image, which is what Prism renders");
      return absl::OkStatus();
    }
    return params.refuse(name, "a crop is not supported; Prism renders the whole image",
                         "the whole image");
  };
  PRISM_RETURN_IF_ERROR(whole_image("cropwindow", {0, 1, 0, 1}));
  PRISM_RETURN_IF_ERROR(
      whole_image("pixelbounds", {0, double(f.x_resolution), 0, double(f.y_resolution)}));
  PRISM_RETURN_IF_ERROR(params.refuse("maxcomponentvalue",
                                      "clamping is not supported; Prism keeps samples unclamped",
                                      "unclamped samples"));
  if (const Parameter* fp16 = params.find("savefp16")) {
    PRISM_ASSIGN_OR_RETURN(bool half, params.get_bool("savefp16", true));
    (void)half;
    if (params.features() != nullptr)
      params.features()->ignored(params.feature(*fp16), fp16->where,
                                 "Prism writes float32 EXRs (the image is the same)");
  }
  PRISM_RETURN_IF_ERROR(params.check_all_used());
  return f;
}

absl::StatusOr<SamplerSpec> make_sampler(const TypeName& type, const ParameterList& params) {
  // Every pbrt-v4 sampler is read (Prism's own sequence draws the samples).
  if (!is_pbrt_type("sampler", type.name)) {
    return unknown_type(
        type, "sampler",
        {"halton", "independent", "paddedsobol", "pmj02bn", "sobol", "stratified", "zsobol"});
  }
  SamplerSpec s;
  s.name = type.name;
  if (type.name == "stratified") {
    PRISM_ASSIGN_OR_RETURN(int x, params.get_int("xsamples", 4));
    PRISM_ASSIGN_OR_RETURN(int y, params.get_int("ysamples", 4));
    PRISM_RETURN_IF_ERROR(check_range(params, "xsamples", x, 1, 4096, "between 1 and 4096"));
    PRISM_RETURN_IF_ERROR(check_range(params, "ysamples", y, 1, 4096, "between 1 and 4096"));
    PRISM_ASSIGN_OR_RETURN(bool jitter, params.get_bool("jitter", true));
    if (!jitter) {
      // Unjittered strata sample fixed positions (pixel centres at one sample), which changes
      // the image as Option "disablepixeljitter" does.
      PRISM_RETURN_IF_ERROR(refuse_value(params, "jitter",
                                         "false samples fixed positions in each pixel, which "
                                         "changes the image; Prism jitters every sample",
                                         "jittered samples"));
    }
    s.samples_per_pixel = x * y;
  } else {
    PRISM_ASSIGN_OR_RETURN(s.samples_per_pixel, params.get_int("pixelsamples", 16));
    PRISM_RETURN_IF_ERROR(check_range(params, "pixelsamples", s.samples_per_pixel, 1, 1 << 24,
                                      "between 1 and 16777216"));
  }
  PRISM_ASSIGN_OR_RETURN(int seed, params.get_int("seed", 0));
  PRISM_ASSIGN_OR_RETURN(std::string randomization, params.get_string("randomization", ""));
  (void)seed;
  (void)randomization;
  PRISM_RETURN_IF_ERROR(params.check_all_used());
  if (params.features() != nullptr)
    params.features()->ignored(
        type_feature("sampler", type), type.where,
        absl::StrCat("Prism uses its own sample sequence; ", s.samples_per_pixel,
                     " samples per pixel become the default spp"));
  return s;
}

absl::StatusOr<IntegratorSpec> make_integrator(const TypeName& type, const ParameterList& params) {
  // Integrators that render something other than the light transport (ambient occlusion,
  // AOVs, a function plot) would give another image: refused.
  static constexpr std::string_view kOtherImage[] = {"ambientocclusion", "aov", "function"};
  IntegratorSpec s;
  s.name = type.name;
  bool other_image = false;
  for (std::string_view k : kOtherImage) other_image |= k == type.name;
  PRISM_ASSIGN_OR_RETURN(s.max_depth, params.get_int("maxdepth", 5));
  PRISM_RETURN_IF_ERROR(
      check_range(params, "maxdepth", s.max_depth, 0, 1024, "between 0 and 1024"));
  const std::string feature = type_feature("integrator", type);
  if (!is_pbrt_type("integrator", type.name)) {
    return unknown_type(type, "integrator",
                        {"bdpt", "lightpath", "mlt", "path", "randomwalk", "simplepath",
                         "simplevolpath", "sppm", "volpath"});
  }
  if (other_image) {
    PRISM_RETURN_IF_ERROR(
        refuse_at(params, feature, type.where,
                  absl::StrCat("integrator \"", type.name,
                               "\" renders something other than the light transport; Prism "
                               "renders path, volpath and the integrators that converge to "
                               "the same image"),
                  "Prism's spectral path tracer"));
  } else if (type.name == "path" || type.name == "volpath") {
    note_supported(params, "integrator", type);
  } else if (params.features() != nullptr) {
    params.features()->ignored(feature, type.where,
                               "converges to the same image; rendered by Prism's spectral "
                               "path tracer");
  }
  // Settings that change the converged image are refused; the rest only tune how fast the
  // replaced integrator converges.
  for (const char* changes : {"regularize", "visualizestrategies", "visualizeweights"}) {
    if (!params.has(changes)) continue;
    PRISM_ASSIGN_OR_RETURN(bool on, params.get_bool(changes, false));
    if (on)
      PRISM_RETURN_IF_ERROR(refuse_value(params, changes, "changes the image; Prism renders it off",
                                         absl::StrCat("'", changes, "' false")));
  }
  for (const Parameter& p : params.parameters()) {
    if (p.used) continue;
    p.used = true;
    if (params.features() != nullptr)
      params.features()->ignored(params.feature(p), p.where,
                                 "integrator tuning does not change the converged image");
  }
  return s;
}

absl::StatusOr<PixelFilterSpec> make_pixel_filter(const TypeName& type,
                                                  const ParameterList& params) {
  PixelFilterSpec f;
  f.where = type.where;
  double radius = 0;
  if (type.name == "box") {
    f.type = PixelFilterType::kBox;
    radius = 0.5;
  } else if (type.name == "gaussian") {
    f.type = PixelFilterType::kGaussian;
    radius = 1.5;
    PRISM_ASSIGN_OR_RETURN(f.sigma, params.get_float("sigma", 0.5));
    PRISM_RETURN_IF_ERROR(
        check_range(params, "sigma", f.sigma, 1e-3, 1e3, "between 0.001 and 1000"));
  } else if (type.name == "triangle") {
    f.type = PixelFilterType::kTriangle;
    radius = 2;
  } else if (type.name == "mitchell") {
    f.type = PixelFilterType::kMitchell;
    radius = 2;
    PRISM_ASSIGN_OR_RETURN(f.b, params.get_float("B", 1.0 / 3.0));
    PRISM_ASSIGN_OR_RETURN(f.c, params.get_float("C", 1.0 / 3.0));
    PRISM_RETURN_IF_ERROR(check_range(params, "B", f.b, -10, 10, "between -10 and 10"));
    PRISM_RETURN_IF_ERROR(check_range(params, "C", f.c, -10, 10, "between -10 and 10"));
  } else if (type.name == "lanczos") {
    f.type = PixelFilterType::kLanczos;
    radius = 4;
    PRISM_ASSIGN_OR_RETURN(f.tau, params.get_float("tau", 3.0));
    PRISM_RETURN_IF_ERROR(check_range(params, "tau", f.tau, 1e-3, 1e3, "between 0.001 and 1000"));
  } else {
    PRISM_RETURN_IF_ERROR(unsupported_type(params, type, "pixel filter",
                                           {"box", "gaussian", "triangle", "mitchell", "lanczos"},
                                           "pbrt-v4's default gaussian filter"));
    return f;
  }
  note_supported(params, "pixel filter", type);
  PRISM_ASSIGN_OR_RETURN(f.x_radius, params.get_float("xradius", radius));
  PRISM_ASSIGN_OR_RETURN(f.y_radius, params.get_float("yradius", radius));
  // A radius beyond 16 pixels would only blur; 0.01 keeps a box a box.
  PRISM_RETURN_IF_ERROR(
      check_range(params, "xradius", f.x_radius, 0.01, 16, "between 0.01 and 16 pixels"));
  PRISM_RETURN_IF_ERROR(
      check_range(params, "yradius", f.y_radius, 0.01, 16, "between 0.01 and 16 pixels"));
  PRISM_RETURN_IF_ERROR(params.check_all_used());
  return f;
}

absl::StatusOr<MaterialKind> make_material(const TypeName& type, const ParameterList& params,
                                           const EntityContext& ctx) {
  MaterialKind kind;
  if (type.name == "diffuse") {
    DiffuseMaterial m;
    PRISM_RETURN_IF_ERROR(read_spectrum_slot(params, "reflectance", SpectrumRole::kReflectance, ctx,
                                             &m.reflectance, &m.reflectance_texture));
    kind = std::move(m);
  } else if (type.name == "dielectric") {
    DielectricMaterial m;
    PRISM_ASSIGN_OR_RETURN(m.eta, read_dielectric_eta(params, ctx));
    PRISM_ASSIGN_OR_RETURN(m.roughness, read_roughness(params, ctx));
    kind = std::move(m);
  } else if (type.name == "conductor") {
    ConductorMaterial m;
    PRISM_ASSIGN_OR_RETURN(
        m.reflectance,
        params.find_spectrum("reflectance", SpectrumRole::kReflectance, ctx.spectra));
    if (m.reflectance && (params.has("eta") || params.has("k")))
      return param_error(params, "reflectance", "cannot be combined with eta or k");
    // The worker samples a conductor's η and k as spectra (metal-*-k is no IOR).
    PRISM_ASSIGN_OR_RETURN(m.eta, spectrum_or(params, "eta", SpectrumRole::kUnbounded, ctx,
                                              SpectrumNamed{"metal-Cu-eta"}));
    PRISM_ASSIGN_OR_RETURN(
        m.k, spectrum_or(params, "k", SpectrumRole::kUnbounded, ctx, SpectrumNamed{"metal-Cu-k"}));
    PRISM_ASSIGN_OR_RETURN(m.roughness, read_roughness(params, ctx));
    kind = std::move(m);
  } else if (type.name == "interface" || type.name == "none" || type.name.empty()) {
    // pbrt-v4 takes "none" and "" as no material: a boundary between media, as "interface".
    kind = InterfaceMaterial{};
  } else if (type.name == "mix") {
    MixMaterial m;
    const Parameter* names = params.find("materials");
    if (names == nullptr || names->type != ParamType::kString || names->strings.size() != 2)
      return location_error(names != nullptr ? names->where : type.where,
                            "mix needs 'string materials' naming two earlier named materials");
    names->used = true;
    for (int i = 0; i < 2; ++i) {
      std::optional<int> index =
          ctx.find_material ? ctx.find_material(names->strings[i]) : std::nullopt;
      if (!index)
        return location_error(names->where, absl::StrCat("mix: named material \"",
                                                         names->strings[i], "\" is not defined"));
      m.materials[i] = *index;
    }
    PRISM_RETURN_IF_ERROR(read_float_slot(params, "amount", ctx, &m.amount, &m.amount_texture));
    if (m.amount_texture < 0)
      PRISM_RETURN_IF_ERROR(check_range(params, "amount", m.amount, 0.0, 1.0, "in [0, 1]"));
    kind = std::move(m);
  } else if (type.name == "thindielectric") {
    ThinDielectricMaterial m;
    PRISM_ASSIGN_OR_RETURN(m.eta, read_dielectric_eta(params, ctx));
    kind = std::move(m);
  } else if (type.name == "diffusetransmission") {
    DiffuseTransmissionMaterial m;
    PRISM_RETURN_IF_ERROR(read_spectrum_slot(params, "reflectance", SpectrumRole::kReflectance, ctx,
                                             &m.reflectance, &m.reflectance_texture));
    PRISM_RETURN_IF_ERROR(read_spectrum_slot(params, "transmittance", SpectrumRole::kReflectance,
                                             ctx, &m.transmittance, &m.transmittance_texture));
    PRISM_ASSIGN_OR_RETURN(m.scale, params.get_float("scale", 1.0));
    PRISM_RETURN_IF_ERROR(check_range(params, "scale", m.scale, 0.0, 1e6, ">= 0"));
    kind = std::move(m);
  } else if (type.name == "coateddiffuse") {
    CoatedDiffuseMaterial m;
    PRISM_RETURN_IF_ERROR(read_spectrum_slot(params, "reflectance", SpectrumRole::kReflectance, ctx,
                                             &m.reflectance, &m.reflectance_texture));
    PRISM_ASSIGN_OR_RETURN(m.eta, read_coat_eta(params, "eta", ctx));
    PRISM_ASSIGN_OR_RETURN(m.roughness, read_roughness(params, ctx));
    PRISM_ASSIGN_OR_RETURN(m.layer, read_layer(params, ctx));
    kind = std::move(m);
  } else if (type.name == "coatedconductor") {
    CoatedConductorMaterial m;
    PRISM_ASSIGN_OR_RETURN(m.interface_eta, read_coat_eta(params, "interface.eta", ctx));
    PRISM_ASSIGN_OR_RETURN(m.interface_roughness, read_roughness(params, ctx, "interface."));
    PRISM_ASSIGN_OR_RETURN(m.conductor_roughness, read_roughness(params, ctx, "conductor."));
    PRISM_ASSIGN_OR_RETURN(
        m.reflectance,
        params.find_spectrum("reflectance", SpectrumRole::kReflectance, ctx.spectra));
    if (m.reflectance && (params.has("conductor.eta") || params.has("conductor.k")))
      return param_error(params, "reflectance", "cannot be combined with conductor.eta or k");
    PRISM_ASSIGN_OR_RETURN(m.conductor_eta,
                           spectrum_or(params, "conductor.eta", SpectrumRole::kUnbounded, ctx,
                                       SpectrumNamed{"metal-Cu-eta"}));
    PRISM_ASSIGN_OR_RETURN(m.k, spectrum_or(params, "conductor.k", SpectrumRole::kUnbounded, ctx,
                                            SpectrumNamed{"metal-Cu-k"}));
    PRISM_ASSIGN_OR_RETURN(m.layer, read_layer(params, ctx));
    kind = std::move(m);
  } else {
    PRISM_RETURN_IF_ERROR(
        unsupported_type(params, type, "material",
                         {"coatedconductor", "coateddiffuse", "conductor", "dielectric", "diffuse",
                          "diffusetransmission", "interface", "mix", "thindielectric"},
                         "pbrt-v4's default material (diffuse, reflectance 0.5)"));
    return MaterialKind{DiffuseMaterial{}};
  }
  if (type.name == "coateddiffuse" || type.name == "coatedconductor")
    note_supported(params, "material", type,
                   "pbrt-v4's stochastic layered BSDF without its two biases "
                   "(docs/conformance.md)");
  else
    note_supported(params, "material", type);
  PRISM_RETURN_IF_ERROR(refuse_common_material_params(params));
  PRISM_RETURN_IF_ERROR(params.check_all_used());
  return kind;
}

absl::StatusOr<TextureKind> make_texture(const TypeName& type, bool spectrum,
                                         const ParameterList& params, const Transform& ctm,
                                         const EntityContext& ctx) {
  TextureKind kind;
  if (type.name == "constant") {
    PRISM_ASSIGN_OR_RETURN(TextureInput value, texture_input(params, "value", spectrum, 1.0, ctx));
    kind = ConstantTexture{std::move(value)};
  } else if (type.name == "checkerboard") {
    PRISM_ASSIGN_OR_RETURN(int dimension, params.get_int("dimension", 2));
    if (dimension != 2)
      PRISM_RETURN_IF_ERROR(refuse_value(params, "dimension",
                                         "is not supported (only 2D checkerboards)",
                                         "a 2D checkerboard in uv"));
    CheckerboardTexture c;
    PRISM_ASSIGN_OR_RETURN(c.mapping, read_uv_mapping(params));
    PRISM_ASSIGN_OR_RETURN(c.tex1, texture_input(params, "tex1", spectrum, 1.0, ctx));
    PRISM_ASSIGN_OR_RETURN(c.tex2, texture_input(params, "tex2", spectrum, 0.0, ctx));
    kind = std::move(c);
  } else if (type.name == "imagemap") {
    ImageTexture t;
    PRISM_ASSIGN_OR_RETURN(t.mapping, read_uv_mapping(params));
    PRISM_ASSIGN_OR_RETURN(std::optional<std::string> filename, params.find_string("filename"));
    if (!filename || filename->empty())
      return location_error(type.where, "imagemap needs a 'string filename'");
    // Image formats pbrt-v4 reads (by extension) and Prism does not: a refusal, listed with the
    // others by `prism check` and substituted under --allow-unsupported.
    const std::string extension =
        absl::AsciiStrToLower(std::filesystem::path(*filename).extension().string());
    for (std::string_view other :
         {".tga", ".pfm", ".jpg", ".jpeg", ".bmp", ".hdr", ".gif", ".tif", ".tiff", ".qoi"}) {
      if (extension != other) continue;
      PRISM_RETURN_IF_ERROR(refuse_at(
          params,
          absl::StrCat(type_feature(spectrum ? "spectrum texture" : "float texture", type),
                       " of a ", extension.substr(1), " image"),
          params.find("filename")->where,
          absl::StrCat("image \"", *filename, "\": Prism reads PNG and OpenEXR textures, not ",
                       extension.substr(1), " (convert it to PNG or EXR)"),
          "a constant 0.5"));
      TextureInput half;
      half.value = 0.5;
      half.spectrum = SpectrumConstant{0.5};
      return TextureKind{ConstantTexture{half}};
    }
    if (!ctx.load_image) return location_error(type.where, "image textures cannot be read here");
    PRISM_ASSIGN_OR_RETURN(EntityContext::LoadedImage loaded,
                           ctx.load_image(*filename, params.find("filename")->where));
    t.filename = loaded.relpath;
    PRISM_ASSIGN_OR_RETURN(t.scale, params.get_float("scale", 1.0));
    PRISM_ASSIGN_OR_RETURN(t.invert, params.get_bool("invert", false));
    PRISM_ASSIGN_OR_RETURN(std::string wrap, params.get_string("wrap", "repeat"));
    if (wrap == "repeat") {
      t.wrap = TextureWrap::kRepeat;
    } else if (wrap == "clamp") {
      t.wrap = TextureWrap::kClamp;
    } else if (wrap == "black") {
      t.wrap = TextureWrap::kBlack;
    } else {
      PRISM_RETURN_IF_ERROR(refuse_value(
          params, "wrap", absl::StrCat("\"", wrap, "\" is not supported (repeat, clamp, black)"),
          "wrap \"repeat\""));
    }
    // pbrt-v4 reads 8-bit PNGs as sRGB unless told otherwise; float images are linear.
    PRISM_ASSIGN_OR_RETURN(std::string encoding, params.get_string("encoding", "sRGB"));
    double gamma = 0;
    if (encoding == "sRGB" || encoding == "linear") {
    } else if (encoding.rfind("gamma ", 0) == 0) {
      absl::StatusOr<double> g =
          parse_finite_number(encoding.substr(6), params.find("encoding")->where, "gamma");
      if (!g.ok() || !(*g > 0))
        return param_error(params, "encoding", "needs a positive exponent after \"gamma \"");
      gamma = *g;
    } else {
      PRISM_RETURN_IF_ERROR(refuse_value(
          params, "encoding",
          absl::StrCat("\"", encoding, "\" is not supported (sRGB, linear, gamma <exponent>)"),
          "sRGB decoding"));
      encoding = "sRGB";
    }
    // Filtering only changes how pbrt-v4 prefilters a minified texture; Prism evaluates the
    // texture itself at each hit (texture_description.h), so these are accepted with a note.
    PRISM_ASSIGN_OR_RETURN(std::string filter, params.get_string("filter", "bilinear"));
    if (filter != "bilinear" && filter != "point" && filter != "trilinear" && filter != "ewa")
      return param_error(
          params, "filter",
          absl::StrCat("\"", filter,
                       "\" is not a pbrt-v4 filter (point, bilinear, trilinear, ewa)"));
    PRISM_ASSIGN_OR_RETURN(double anisotropy, params.get_float("maxanisotropy", 8.0));
    (void)anisotropy;
    if (!loaded.eight_bit || encoding == "linear") {
      t.image = loaded.image;
    } else {
      auto decoded = std::make_shared<TextureImage>(*loaded.image);
      for (float& v : decoded->values)
        v = float(gamma > 0 ? std::pow(double(v), gamma) : srgb_to_linear(double(v)));
      t.image = std::move(decoded);
    }
    kind = std::move(t);
  } else if (type.name == "scale") {
    ScaleTexture t;
    PRISM_ASSIGN_OR_RETURN(t.tex, texture_input(params, "tex", spectrum, 1.0, ctx));
    PRISM_ASSIGN_OR_RETURN(t.scale, texture_input(params, "scale", false, 1.0, ctx));
    kind = std::move(t);
  } else if (type.name == "mix") {
    MixTexture t;
    PRISM_ASSIGN_OR_RETURN(t.tex1, texture_input(params, "tex1", spectrum, 0.0, ctx));
    PRISM_ASSIGN_OR_RETURN(t.tex2, texture_input(params, "tex2", spectrum, 1.0, ctx));
    PRISM_ASSIGN_OR_RETURN(t.amount, texture_input(params, "amount", false, 0.5, ctx));
    kind = std::move(t);
  } else if (type.name == "directionmix") {
    DirectionMixTexture t;
    PRISM_ASSIGN_OR_RETURN(t.tex1, texture_input(params, "tex1", spectrum, 0.0, ctx));
    PRISM_ASSIGN_OR_RETURN(t.tex2, texture_input(params, "tex2", spectrum, 1.0, ctx));
    PRISM_ASSIGN_OR_RETURN(std::vector<Vec3> dir, params.get_triples("dir", ParamType::kVector3));
    Vec3 d = dir.empty() ? Vec3{0, 1, 0} : dir[0];
    if (dir.size() > 1) return param_error(params, "dir", "takes one vector");
    d = ctm.apply_vector(d);
    const double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (!(len > 0)) return param_error(params, "dir", "must not be zero");
    t.direction_world = {d[0] / len, d[1] / len, d[2] / len};
    kind = std::move(t);
  } else {
    PRISM_RETURN_IF_ERROR(
        unsupported_type(params, type, spectrum ? "spectrum texture" : "float texture",
                         {"checkerboard", "constant", "directionmix", "imagemap", "mix", "scale"},
                         "a constant 0.5"));
    TextureInput half;
    half.value = 0.5;
    half.spectrum = SpectrumConstant{0.5};
    return TextureKind{ConstantTexture{half}};
  }
  const char* what = spectrum ? "spectrum texture" : "float texture";
  if ((type.name == "imagemap" || type.name == "checkerboard") && params.features() != nullptr)
    params.features()->approximated(
        type_feature(what, type), type.where,
        "looked up at each hit without pbrt-v4's ray-differential filtering; texture detail "
        "smaller than a pixel converges to its pixel-filtered average instead of pbrt-v4's "
        "prefiltered (slightly blurrier) one");
  else
    note_supported(params, what, type);
  PRISM_RETURN_IF_ERROR(params.check_all_used());
  return kind;
}

// A light switched off: a scale of 0, or a radiance or intensity of `rgb [0 0 0]` or `float 0`.
// pbrt-v4 renders it black; Prism drops it (an area light's shapes stay, with their material).
bool emits_nothing(const SpectrumParam& spectrum, double scale) {
  const auto* rgb = std::get_if<SpectrumRgb>(&spectrum);
  const auto* constant = std::get_if<SpectrumConstant>(&spectrum);
  return scale == 0.0 || (rgb != nullptr && rgb->r == 0.0 && rgb->g == 0.0 && rgb->b == 0.0) ||
         (constant != nullptr && constant->value == 0.0);
}

void note_dark(const ParameterList& params, const TypeName& type, absl::string_view what) {
  if (params.features() == nullptr) return;
  params.features()->ignored(
      absl::StrCat(what, " emitting nothing"), type.where,
      absl::StrCat("its ", what == "area light" ? "radiance" : "emission",
                   " or scale is 0: it is left out, as pbrt-v4 renders "
                   "it black",
                   what == "area light" ? " (its shapes stay, with their material)" : ""));
}

// A light's emission parameters, read in pbrt-v4's order: the spectrum `name` (the default
// illuminant when absent) into `spectrum`, `scale` (>= 0), and the optional positive
// `normalisation` ("power" or "illuminance") into `normalised`; `dark` is set when the light
// emits nothing (emits_nothing).
template <typename L>
absl::Status read_emission(const ParameterList& params, const EntityContext& ctx,
                           const std::string& name, SpectrumParam L::*spectrum,
                           const std::string& normalisation, std::optional<double> L::*normalised,
                           L& light, bool* dark) {
  PRISM_ASSIGN_OR_RETURN(light.*spectrum, spectrum_or(params, name, SpectrumRole::kIlluminant, ctx,
                                                      SpectrumNamed{kDefaultIlluminant}));
  PRISM_ASSIGN_OR_RETURN(light.scale, params.get_float("scale", 1.0));
  PRISM_RETURN_IF_ERROR(
      check_range(params, "scale", light.scale, 0.0, std::numeric_limits<double>::max(), ">= 0"));
  PRISM_ASSIGN_OR_RETURN(light.*normalised, positive_optional(params, normalisation));
  *dark = emits_nothing(light.*spectrum, light.scale);
  return absl::OkStatus();
}

absl::StatusOr<std::optional<Light>> make_light(const TypeName& type, const ParameterList& params,
                                                const Transform& ctm, const EntityContext& ctx) {
  Light light;
  light.where = type.where;
  bool dark = false;
  if (type.name == "point") {
    PointLight p;
    PRISM_RETURN_IF_ERROR(read_emission(params, ctx, "I", &PointLight::intensity, "power",
                                        &PointLight::power, p, &dark));
    PRISM_ASSIGN_OR_RETURN(Vec3 from, params.get_point3("from", {0, 0, 0}));
    light.light_to_world = ctm * Transform::translate(from);
    p.position_world = light.light_to_world.apply_point({0, 0, 0});
    light.kind = std::move(p);
  } else if (type.name == "goniometric") {
    PointLight p;
    PRISM_RETURN_IF_ERROR(read_emission(params, ctx, "I", &PointLight::intensity, "power",
                                        &PointLight::power, p, &dark));
    PRISM_ASSIGN_OR_RETURN(std::optional<std::string> filename, params.find_string("filename"));
    if (!filename || filename->empty())
      return location_error(type.where, "goniometric light needs a 'string filename'");
    PRISM_ASSIGN_OR_RETURN(LightImage loaded, read_light_image(params, type, ctx, *filename,
                                                               "a goniometric (equal-area) image"));
    auto grey = std::make_shared<TextureImage>();
    grey->width = loaded.image->width;
    grey->height = loaded.image->height;
    grey->channels = 1;
    const int c = loaded.image->channels;
    for (size_t i = 0; i < loaded.image->values.size(); i += size_t(c)) {
      double sum = 0;
      for (int k = 0; k < c; ++k) sum += loaded.image->values[i + size_t(k)];
      grey->values.push_back(float(sum / c));
    }
    p.goniometric = std::move(grey);
    p.filename = loaded.relpath;
    light.light_to_world = ctm;
    p.position_world = light.light_to_world.apply_point({0, 0, 0});
    light.kind = std::move(p);
  } else if (type.name == "projection") {
    PointLight p;
    PRISM_ASSIGN_OR_RETURN(p.scale, params.get_float("scale", 1.0));
    PRISM_RETURN_IF_ERROR(
        check_range(params, "scale", p.scale, 0.0, std::numeric_limits<double>::max(), ">= 0"));
    dark = p.scale == 0.0;
    PRISM_ASSIGN_OR_RETURN(p.power, positive_optional(params, "power"));
    PRISM_ASSIGN_OR_RETURN(p.fov_deg, params.get_float("fov", 90.0));
    PRISM_RETURN_IF_ERROR(check_range(params, "fov", p.fov_deg, 1e-3, 179.9, "in (0, 180)"));
    PRISM_ASSIGN_OR_RETURN(std::optional<std::string> filename, params.find_string("filename"));
    if (!filename || filename->empty())
      return location_error(type.where, "projection light needs a 'string filename'");
    PRISM_ASSIGN_OR_RETURN(LightImage loaded, read_light_image(params, type, ctx, *filename, ""));
    p.projection = loaded.image;
    p.filename = loaded.relpath;
    light.light_to_world = ctm;
    p.position_world = light.light_to_world.apply_point({0, 0, 0});
    light.kind = std::move(p);
  } else if (type.name == "spot") {
    SpotLight s;
    PRISM_RETURN_IF_ERROR(read_emission(params, ctx, "I", &SpotLight::intensity, "power",
                                        &SpotLight::power, s, &dark));
    PRISM_ASSIGN_OR_RETURN(Vec3 from, params.get_point3("from", {0, 0, 0}));
    PRISM_ASSIGN_OR_RETURN(Vec3 to, params.get_point3("to", {0, 0, 1}));
    PRISM_ASSIGN_OR_RETURN(s.cone_angle_deg, params.get_float("coneangle", 30.0));
    PRISM_ASSIGN_OR_RETURN(s.cone_delta_angle_deg, params.get_float("conedeltaangle", 5.0));
    PRISM_RETURN_IF_ERROR(
        check_range(params, "coneangle", s.cone_angle_deg, 1e-9, 180.0, "in (0, 180] degrees"));
    PRISM_RETURN_IF_ERROR(check_range(params, "conedeltaangle", s.cone_delta_angle_deg, 0.0,
                                      s.cone_angle_deg, "between 0 and coneangle"));
    Vec3 dir{to[0] - from[0], to[1] - from[1], to[2] - from[2]};
    if (dir[0] == 0 && dir[1] == 0 && dir[2] == 0)
      return location_error(type.where, "spot light needs 'from' and 'to' to differ");
    light.light_to_world = ctm * Transform::translate(from) * frame_from_z(dir);
    s.position_world = light.light_to_world.apply_point({0, 0, 0});
    s.direction_world = normalize(light.light_to_world.apply_vector({0, 0, 1}));
    light.kind = std::move(s);
  } else if (type.name == "infinite") {
    InfiniteLight i;
    PRISM_ASSIGN_OR_RETURN(i.portal, read_portal(params));
    PRISM_ASSIGN_OR_RETURN(std::optional<std::string> filename, params.find_string("filename"));
    if (filename && !filename->empty()) {
      if (params.has("L"))
        return param_error(params, "L", "cannot be combined with an image 'filename'");
      PRISM_ASSIGN_OR_RETURN(LightImage loaded, read_light_image(params, type, ctx, *filename,
                                                                 "an equal-area environment map"));
      i.filename = loaded.relpath;
      i.image = loaded.image;
    }
    if (i.portal && !i.image) {
      return param_error(params, "portal",
                         "needs an image 'filename' (pbrt-v4 has no portal for a constant 'L')");
    }
    PRISM_RETURN_IF_ERROR(read_emission(params, ctx, "L", &InfiniteLight::radiance, "illuminance",
                                        &InfiniteLight::illuminance, i, &dark));
    light.light_to_world = ctm;
    light.kind = std::move(i);
  } else if (type.name == "distant") {
    DistantLight d;
    PRISM_RETURN_IF_ERROR(read_emission(params, ctx, "L", &DistantLight::radiance, "illuminance",
                                        &DistantLight::illuminance, d, &dark));
    PRISM_ASSIGN_OR_RETURN(Vec3 from, params.get_point3("from", {0, 0, 0}));
    PRISM_ASSIGN_OR_RETURN(Vec3 to, params.get_point3("to", {0, 0, 1}));
    const Vec3 w{from[0] - to[0], from[1] - to[1], from[2] - to[2]};
    if (w[0] == 0 && w[1] == 0 && w[2] == 0)
      return location_error(type.where, "distant light needs 'from' and 'to' to differ");
    light.light_to_world = ctm;
    const Vec3 world = ctm.apply_vector(w);
    if (!(world[0] != 0 || world[1] != 0 || world[2] != 0))
      return location_error(type.where, "distant light's direction vanishes under the transform");
    d.direction_world = normalize(world);
    light.kind = std::move(d);
  } else {
    PRISM_RETURN_IF_ERROR(
        unsupported_type(params, type, "light",
                         {"distant", "goniometric", "infinite", "point", "projection", "spot"},
                         "the scene without this light"));
    return std::optional<Light>();
  }
  PRISM_RETURN_IF_ERROR(params.check_all_used());
  if (dark) {
    note_dark(params, type, "light");
    return std::optional<Light>();
  }
  note_supported(params, "light", type);
  return std::optional<Light>(std::move(light));
}

absl::StatusOr<std::optional<AreaLight>> make_area_light(const TypeName& type,
                                                         const ParameterList& params,
                                                         const EntityContext& ctx) {
  if (type.name != "diffuse") {
    PRISM_RETURN_IF_ERROR(
        unsupported_type(params, type, "area light", {"diffuse"}, "shapes that do not emit"));
    return std::optional<AreaLight>();
  }
  note_supported(params, "area light", type);
  PRISM_RETURN_IF_ERROR(
      params.refuse("filename", "image area lights are not supported", "the uniform radiance 'L'"));
  AreaLight a;
  a.where = type.where;
  PRISM_ASSIGN_OR_RETURN(a.radiance, spectrum_or(params, "L", SpectrumRole::kIlluminant, ctx,
                                                 SpectrumNamed{kDefaultIlluminant}));
  PRISM_ASSIGN_OR_RETURN(a.scale, params.get_float("scale", 1.0));
  PRISM_RETURN_IF_ERROR(
      check_range(params, "scale", a.scale, 0.0, std::numeric_limits<double>::max(), ">= 0"));
  PRISM_ASSIGN_OR_RETURN(a.two_sided, params.get_bool("twosided", false));
  PRISM_ASSIGN_OR_RETURN(a.power, positive_optional(params, "power"));
  PRISM_RETURN_IF_ERROR(params.check_all_used());
  if (emits_nothing(a.radiance, a.scale)) {
    note_dark(params, type, "area light");
    return std::optional<AreaLight>();
  }
  return std::optional<AreaLight>(std::move(a));
}

absl::StatusOr<Medium> make_medium(const TypeName& type, const ParameterList& params,
                                   const EntityContext& ctx) {
  if (type.name != "homogeneous") {
    PRISM_RETURN_IF_ERROR(unsupported_type(params, type, "medium", {"homogeneous"},
                                           "a vacuum (no absorption, no scattering)"));
    Medium m;
    m.kind = HomogeneousMedium{SpectrumConstant{0.0}, SpectrumConstant{0.0}, 1.0, 0.0};
    m.where = type.where;
    return m;
  }
  note_supported(params, "medium", type);
  PRISM_RETURN_IF_ERROR(params.refuse(
      "preset", "named scattering presets are not supported; give sigma_a and sigma_s",
      "sigma_a and sigma_s as given (default 1)"));
  // An emission of zero (an exporter's default `rgb Le [0 0 0]`) emits nothing: accepted.
  const Parameter* le = params.find("Le");
  const bool dark_le =
      le != nullptr && !le->numbers.empty() &&
      std::all_of(le->numbers.begin(), le->numbers.end(), [](double v) { return v == 0.0; }) &&
      le->strings.empty();
  if (le == nullptr || dark_le) {
    for (const char* name : {"Le", "Lescale"}) {
      if (const Parameter* p = params.find(name)) {
        p->used = true;
        if (params.features() != nullptr) {
          params.features()->ignored(params.feature(*p), p->where,
                                     "the medium's emission is zero (or not given)");
        }
      }
    }
  } else {
    PRISM_RETURN_IF_ERROR(
        params.refuse("Le", "emissive media are not supported", "a medium that does not emit"));
    PRISM_RETURN_IF_ERROR(params.refuse("Lescale", "emissive media are not supported",
                                        "a medium that does not emit"));
  }
  HomogeneousMedium h;
  PRISM_ASSIGN_OR_RETURN(h.sigma_a, spectrum_or(params, "sigma_a", SpectrumRole::kUnbounded, ctx,
                                                SpectrumConstant{1.0}));
  PRISM_ASSIGN_OR_RETURN(h.sigma_s, spectrum_or(params, "sigma_s", SpectrumRole::kUnbounded, ctx,
                                                SpectrumConstant{1.0}));
  PRISM_ASSIGN_OR_RETURN(h.scale, params.get_float("scale", 1.0));
  PRISM_RETURN_IF_ERROR(check_range(params, "scale", h.scale, 0.0, 1e30, ">= 0"));
  PRISM_ASSIGN_OR_RETURN(h.g, params.get_float("g", 0.0));
  PRISM_RETURN_IF_ERROR(check_range(params, "g", h.g, -0.999999, 0.999999, "in (-1, 1)"));
  PRISM_RETURN_IF_ERROR(params.check_all_used());
  Medium m;
  m.kind = std::move(h);
  m.where = type.where;
  return m;
}

absl::Status read_shape_alpha(const ParameterList& params, const EntityContext& ctx, double* alpha,
                              int* alpha_texture) {
  PRISM_RETURN_IF_ERROR(read_float_slot(params, "alpha", ctx, alpha, alpha_texture));
  if (*alpha_texture < 0)
    PRISM_RETURN_IF_ERROR(check_range(params, "alpha", *alpha, 0.0, 1.0, "in [0, 1]"));
  return absl::OkStatus();
}

absl::StatusOr<std::optional<ShapeGeometry>> make_shape_geometry(const TypeName& type,
                                                                 const ParameterList& params,
                                                                 const EntityContext& ctx) {
  ShapeGeometry geometry;
  PRISM_RETURN_IF_ERROR(params.refuse("emissionfilename", "image area lights are not supported",
                                      "the area light's uniform radiance 'L'"));
  if (type.name == "trianglemesh" || type.name == "bilinearmesh") {
    PRISM_RETURN_IF_ERROR(params.refuse("S", "per-vertex tangents are not supported",
                                        "tangents from the surface's uv parametrisation"));
    // Face indices only select ptex faces, and Prism has no ptex texture to select them.
    if (const Parameter* p = params.find("faceIndices")) {
      p->used = true;
      if (params.features() != nullptr)
        params.features()->ignored(params.feature(*p), p->where,
                                   "face indices only address ptex textures, which Prism does "
                                   "not read");
    }
    bool bilinear = type.name == "bilinearmesh";
    PRISM_ASSIGN_OR_RETURN(std::shared_ptr<TriangleMeshData> mesh,
                           inline_mesh(params, bilinear, type, ctx));
    geometry = TriangleMeshShape{std::move(mesh), type.name};
  } else if (type.name == "plymesh" || type.name == "objmesh") {
    // An empty displacement texture name is no displacement (pbrt-v4 looks it up only when
    // non-empty), and edgelength only tunes a displacement's tessellation.
    const Parameter* displacement = params.find("displacement");
    const bool displaced = displacement != nullptr &&
                           !(displacement->strings.size() == 1 && displacement->strings[0].empty());
    if (displaced) {
      PRISM_RETURN_IF_ERROR(
          params.refuse("displacement", "displacement is not supported", "the undisplaced mesh"));
      PRISM_RETURN_IF_ERROR(
          params.refuse("edgelength", "displacement is not supported", "the undisplaced mesh"));
    } else {
      for (const char* name : {"displacement", "edgelength"}) {
        if (const Parameter* p = params.find(name)) {
          p->used = true;
          if (params.features() != nullptr) {
            params.features()->ignored(params.feature(*p), p->where,
                                       "no displacement texture is named, so nothing is "
                                       "displaced or tessellated");
          }
        }
      }
    }
    PRISM_ASSIGN_OR_RETURN(std::optional<std::string> filename, params.find_string("filename"));
    if (!filename)
      return location_error(type.where,
                            absl::StrCat("\"", type.name, "\" needs 'string filename'"));
    if (!ctx.load_mesh) return param_error(params, "filename", "cannot be read here");
    const Parameter* p = params.find("filename");
    PRISM_ASSIGN_OR_RETURN(
        TriangleMeshShape shape,
        ctx.load_mesh(*filename, type.name == "plymesh" ? MeshFormat::kPly : MeshFormat::kObj,
                      p->where));
    geometry = std::move(shape);
  } else if (type.name == "sphere") {
    SphereShape s;
    PRISM_ASSIGN_OR_RETURN(s.radius, params.get_float("radius", 1.0));
    PRISM_RETURN_IF_ERROR(check_range(params, "radius", s.radius, 1e-30, 1e30, "> 0"));
    PRISM_ASSIGN_OR_RETURN(double zmin, params.get_float("zmin", -s.radius));
    PRISM_ASSIGN_OR_RETURN(double zmax, params.get_float("zmax", s.radius));
    PRISM_ASSIGN_OR_RETURN(double phimax, params.get_float("phimax", 360.0));
    if (zmin > -s.radius)
      PRISM_RETURN_IF_ERROR(refuse_value(params, "zmin",
                                         "is not supported (only full spheres: zmin <= -radius)",
                                         "a full sphere"));
    if (zmax < s.radius)
      PRISM_RETURN_IF_ERROR(refuse_value(
          params, "zmax", "is not supported (only full spheres: zmax >= radius)", "a full sphere"));
    if (phimax < 360.0)
      PRISM_RETURN_IF_ERROR(refuse_value(params, "phimax",
                                         "is not supported (only full spheres: phimax >= 360)",
                                         "a full sphere"));
    geometry = s;
  } else if (type.name == "disk") {
    DiskShape disk;
    PRISM_ASSIGN_OR_RETURN(disk.height, params.get_float("height", 0.0));
    PRISM_ASSIGN_OR_RETURN(disk.radius, params.get_float("radius", 1.0));
    PRISM_ASSIGN_OR_RETURN(disk.inner_radius, params.get_float("innerradius", 0.0));
    PRISM_ASSIGN_OR_RETURN(double phimax, params.get_float("phimax", 360.0));
    PRISM_RETURN_IF_ERROR(check_range(params, "radius", disk.radius, 1e-30, 1e30, "> 0"));
    if (!(disk.inner_radius >= 0 && disk.inner_radius < disk.radius))
      return param_error(params, "innerradius", "must be in [0, radius)");
    if (phimax < 360.0)
      PRISM_RETURN_IF_ERROR(refuse_value(
          params, "phimax", "is not supported (only full disks: phimax >= 360)", "a full disk"));
    geometry = disk;
  } else if (type.name == "loopsubdiv") {
    PRISM_ASSIGN_OR_RETURN(int levels, params.get_int("levels", 3));
    PRISM_RETURN_IF_ERROR(check_range(params, "levels", levels, 0, kMaxLoopLevels,
                                      absl::StrCat("in [0, ", kMaxLoopLevels, "]")));
    PRISM_ASSIGN_OR_RETURN(std::vector<Vec3> p, params.get_triples("P", ParamType::kPoint3));
    PRISM_ASSIGN_OR_RETURN(std::vector<std::int64_t> indices, params.get_ints("indices"));
    if (p.empty() || indices.empty())
      return location_error(type.where, "\"loopsubdiv\" needs 'point3 P' and 'integer indices'");
    if (indices.size() % 3 != 0)
      return param_error(params, "indices",
                         absl::StrCat("needs a multiple of 3 values, got ", indices.size()));
    std::vector<Float3> positions;
    positions.reserve(p.size());
    for (const Vec3& v : p) positions.push_back({float(v[0]), float(v[1]), float(v[2])});
    std::vector<Triangle> triangles;
    for (size_t i = 0; i < indices.size(); i += 3) {
      for (size_t k = 0; k < 3; ++k) {
        if (indices[i + k] < 0 || size_t(indices[i + k]) >= p.size())
          return param_error(params, "indices",
                             absl::StrCat("refers to vertex ", indices[i + k], " but 'P' has ",
                                          p.size(), " vertices"));
      }
      triangles.push_back({std::uint32_t(indices[i]), std::uint32_t(indices[i + 1]),
                           std::uint32_t(indices[i + 2])});
    }
    absl::StatusOr<TriangleMeshData> mesh =
        loop_subdivide(positions, triangles, levels, ctx.mesh_limits.max_triangles);
    if (!mesh.ok()) {
      return absl::Status(
          mesh.status().code(),
          absl::StrCat(type.where.to_string(), ": loopsubdiv: ", mesh.status().message()));
    }
    // pbrt-v4's limit normals, cross(S, T) over its one-ring order, point away from the side the
    // control triangles' winding faces, and pbrt-v4 turns the geometric normal to the shading
    // normal: the surface's outside is on the far side of its winding. Prism follows, so
    // one-sided emission and a dielectric's inside are where pbrt-v4 puts them.
    for (Float3& n : mesh->normals) n = {-n.x, -n.y, -n.z};
    geometry =
        TriangleMeshShape{std::make_shared<const TriangleMeshData>(*std::move(mesh)), "loopsubdiv"};
  } else if (type.name == "cylinder") {
    CylinderShape c;
    PRISM_ASSIGN_OR_RETURN(c.radius, params.get_float("radius", 1.0));
    PRISM_ASSIGN_OR_RETURN(c.z_min, params.get_float("zmin", -1.0));
    PRISM_ASSIGN_OR_RETURN(c.z_max, params.get_float("zmax", 1.0));
    PRISM_ASSIGN_OR_RETURN(double phimax, params.get_float("phimax", 360.0));
    PRISM_RETURN_IF_ERROR(check_range(params, "radius", c.radius, 1e-30, 1e30, "> 0"));
    if (c.z_min > c.z_max) std::swap(c.z_min, c.z_max);  // pbrt-v4 orders them too
    if (!(c.z_max > c.z_min))
      return location_error(type.where, "cylinder needs zmin and zmax to differ");
    if (phimax < 360.0)
      PRISM_RETURN_IF_ERROR(refuse_value(params, "phimax",
                                         "is not supported (only full cylinders: phimax >= 360)",
                                         "a full cylinder"));
    geometry = c;
  } else {
    PRISM_RETURN_IF_ERROR(unsupported_type(params, type, "shape",
                                           {"bilinearmesh", "cylinder", "disk", "loopsubdiv",
                                            "objmesh", "plymesh", "sphere", "trianglemesh"},
                                           "the scene without this shape"));
    return std::optional<ShapeGeometry>();
  }
  note_supported(params, "shape", type);
  PRISM_RETURN_IF_ERROR(params.check_all_used());
  return std::optional<ShapeGeometry>(std::move(geometry));
}

}  // namespace prism::scene
