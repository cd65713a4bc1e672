// Mesh files: PLY (DESIGN.md fixes the output layout exactly), binary STL, OBJ, and a PLY reader.

#include <Eigen/Geometry>
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "mesh/mesh.h"

namespace sonomesh::mesh {
namespace {

static_assert(std::endian::native == std::endian::little,
              "PLY/STL writers assume a little-endian host");

MeshIoError io_error(MeshIoError::Code code, const std::filesystem::path& path,
                     const std::string& what) {
  return {code, path.string() + ": " + what};
}

std::optional<MeshIoError> finish(std::ofstream& out, const std::filesystem::path& path) {
  out.flush();
  if (!out) return io_error(MeshIoError::Code::WriteFailed, path, "write failed (disk full?)");
  return std::nullopt;
}

template <class T>
void put(std::string& buf, const T& value) {
  const auto* p = reinterpret_cast<const char*>(&value);
  buf.append(p, p + sizeof(T));
}

std::optional<MeshIoError> write_ply_impl(const Mesh& mesh, const std::vector<StopReason>* stop,
                                          const std::filesystem::path& path) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) return io_error(MeshIoError::Code::OpenFailed, path, "cannot open for writing");
  // SPACE=LPS: 3D Slicer 4.11+ then loads the mesh in place over the volume (world frame, mm).
  std::string header = "ply\nformat binary_little_endian 1.0\ncomment SPACE=LPS\nelement vertex " +
                       std::to_string(mesh.vertices.size()) +
                       "\nproperty float x\nproperty float y\nproperty float z\n";
  if (stop) header += "property uchar stop\n";
  header += "element face " + std::to_string(mesh.triangles.size()) +
            "\nproperty list uchar int vertex_indices\nend_header\n";
  std::string body;
  body.reserve(mesh.vertices.size() * 13 + mesh.triangles.size() * 13);
  for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
    for (int a = 0; a < 3; ++a) put(body, mesh.vertices[v][a]);
    if (stop) put(body, static_cast<std::uint8_t>((*stop)[v]));
  }
  for (const auto& t : mesh.triangles) {
    put(body, std::uint8_t{3});
    for (auto i : t) put(body, static_cast<std::int32_t>(i));
  }
  out.write(header.data(), std::streamsize(header.size()));
  out.write(body.data(), std::streamsize(body.size()));
  return finish(out, path);
}

// ---- reader ----

enum class Type { I8, U8, I16, U16, I32, U32, F32, F64 };

std::optional<Type> parse_type(const std::string& s) {
  if (s == "char" || s == "int8") return Type::I8;
  if (s == "uchar" || s == "uint8") return Type::U8;
  if (s == "short" || s == "int16") return Type::I16;
  if (s == "ushort" || s == "uint16") return Type::U16;
  if (s == "int" || s == "int32") return Type::I32;
  if (s == "uint" || s == "uint32") return Type::U32;
  if (s == "float" || s == "float32") return Type::F32;
  if (s == "double" || s == "float64") return Type::F64;
  return std::nullopt;
}

int type_size(Type t) {
  switch (t) {
    case Type::I8:
    case Type::U8:
      return 1;
    case Type::I16:
    case Type::U16:
      return 2;
    case Type::I32:
    case Type::U32:
    case Type::F32:
      return 4;
    case Type::F64:
      return 8;
  }
  return 0;
}

struct Property {
  std::string name;
  Type type = Type::F32;
  bool is_list = false;
  Type count_type = Type::U8;
};
struct Element {
  std::string name;
  std::size_t count = 0;
  std::vector<Property> properties;
};

// A little-endian T from its bytes at b.
template <typename T>
double load(const char* b) {
  T x;
  std::memcpy(&x, b, sizeof x);
  return static_cast<double>(x);
}

// Reads one scalar as double, from binary bytes or ascii tokens.
class Source {
 public:
  Source(std::istream& in, bool ascii) : in_(in), ascii_(ascii) {}
  bool read(Type t, double* value) {
    if (ascii_) return static_cast<bool>(in_ >> *value);
    char b[8];
    if (!in_.read(b, type_size(t))) return false;
    switch (t) {
      case Type::I8:
        *value = load<std::int8_t>(b);
        break;
      case Type::U8:
        *value = load<std::uint8_t>(b);
        break;
      case Type::I16:
        *value = load<std::int16_t>(b);
        break;
      case Type::U16:
        *value = load<std::uint16_t>(b);
        break;
      case Type::I32:
        *value = load<std::int32_t>(b);
        break;
      case Type::U32:
        *value = load<std::uint32_t>(b);
        break;
      case Type::F32:
        *value = load<float>(b);
        break;
      case Type::F64:
        *value = load<double>(b);
        break;
    }
    return true;
  }

 private:
  std::istream& in_;
  bool ascii_;
};

// A reader failure before the path is attached.
struct Failure {
  MeshIoError::Code code;
  std::string what;
};
using Failed = std::optional<Failure>;

Failed bad_header(const std::string& what) { return Failure{MeshIoError::Code::BadHeader, what}; }

// One `property` line (after the word), appended to the current element.
Failed parse_property(std::istringstream& ls, const std::string& line, Element& element) {
  Property p;
  std::string t;
  ls >> t;
  if (t == "list") {
    std::string ct, it;
    ls >> ct >> it >> p.name;
    const auto c = parse_type(ct), i = parse_type(it);
    // A count is of an integer type (a float one read NaN; found by fuzz_ply).
    if (!c || !i || *c == Type::F32 || *c == Type::F64)
      return bad_header("bad list property: " + line);
    p.is_list = true;
    p.count_type = *c;
    p.type = *i;
  } else {
    const auto ty = parse_type(t);
    ls >> p.name;
    if (!ty) return bad_header("bad property type: " + line);
    p.type = *ty;
  }
  element.properties.push_back(p);
  return std::nullopt;
}

// One header line other than end_header; sets ascii and have_format from the format line.
Failed parse_header_line(const std::string& line, bool& ascii, bool& have_format,
                         std::vector<Element>& elements) {
  std::istringstream ls(line);
  std::string word;
  ls >> word;
  if (word == "comment" || word == "obj_info" || word.empty()) return std::nullopt;
  if (word == "format") {
    std::string fmt;
    ls >> fmt;
    if (fmt == "ascii")
      ascii = true;
    else if (fmt != "binary_little_endian")
      return Failure{MeshIoError::Code::Unsupported, "format '" + fmt + "' not supported"};
    have_format = true;
  } else if (word == "element") {
    Element e;
    long long count = -1;
    ls >> e.name >> count;
    if (!ls || count < 0) return bad_header("bad element line: " + line);
    e.count = static_cast<std::size_t>(count);
    elements.push_back(e);
  } else if (word == "property") {
    if (elements.empty()) return bad_header("property before element");
    return parse_property(ls, line, elements.back());
  } else {
    return bad_header("unknown header line: " + line);
  }
  return std::nullopt;
}

// The header after the "ply" line, up to and including end_header.
Failed read_header(std::istream& in, bool& ascii, std::vector<Element>& elements) {
  bool have_format = false;
  std::string line;
  for (;;) {
    if (!std::getline(in, line))
      return Failure{MeshIoError::Code::Truncated, "header ends before end_header"};
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream ls(line);
    std::string word;
    ls >> word;
    if (word == "end_header") break;
    if (Failed f = parse_header_line(line, ascii, have_format, elements)) return f;
  }
  if (!have_format) return bad_header("no format line");
  return std::nullopt;
}

// Which property of an element is which (-1: absent).
struct Columns {
  int x = -1, y = -1, z = -1, stop = -1, indices = -1;
};

Columns columns(const Element& e) {
  Columns c;
  for (int p = 0; p < static_cast<int>(e.properties.size()); ++p) {
    const auto& n = e.properties[p].name;
    if (n == "x") c.x = p;
    if (n == "y") c.y = p;
    if (n == "z") c.z = p;
    if (n == "stop") c.stop = p;
    if ((n == "vertex_indices" || n == "vertex_index") && e.properties[p].is_list) c.indices = p;
  }
  return c;
}

// One list property of item n; a face's vertex indices become triangles (polygons as fans). An
// index must be a whole number naming a vertex (the tests are false for NaN).
Failed read_list(Source& src, const Property& prop, const Element& e, std::size_t n, bool indices,
                 std::vector<double>& list, Mesh& mesh) {
  double value = 0.0;
  if (!src.read(prop.count_type, &value) || !(value >= 0 && value <= 1e6))
    return Failure{MeshIoError::Code::Truncated, "truncated or bad list in element " + e.name};
  list.resize(static_cast<std::size_t>(value));
  for (auto& x : list)
    if (!src.read(prop.type, &x))
      return Failure{MeshIoError::Code::Truncated, "truncated list in element " + e.name};
  if (!indices) return std::nullopt;
  for (double x : list)
    if (!(x >= 0 && x < double(mesh.vertices.size()) && x == std::floor(x)))
      return Failure{MeshIoError::Code::BadIndex,
                     "face " + std::to_string(n) + " indexes a missing vertex"};
  for (std::size_t k = 1; k + 1 < list.size(); ++k)
    mesh.triangles.push_back(
        {std::uint32_t(list[0]), std::uint32_t(list[k]), std::uint32_t(list[k + 1])});
  return std::nullopt;
}

// Property p of vertex n. A stop reason is a small code; anything else is not a balloon file's
// (found by fuzz_ply: the cast of an out-of-range value is undefined).
Failed store_vertex_value(const Columns& c, int p, std::size_t n, double value, MeshReadResult& r) {
  if (p == c.x) r.mesh.vertices[n].x() = float(value);
  if (p == c.y) r.mesh.vertices[n].y() = float(value);
  if (p == c.z) r.mesh.vertices[n].z() = float(value);
  if (p == c.stop) {
    if (!(value >= 0 && value <= 255 && value == std::floor(value)))
      return bad_header("vertex " + std::to_string(n) + " has stop value " + std::to_string(value) +
                        ", not a stop reason code");
    r.stop[n] = static_cast<std::uint8_t>(value);
  }
  return std::nullopt;
}

// The items of one element; vertices and faces are kept, other elements are read past.
Failed read_element(Source& src, const Element& e, MeshReadResult& r, bool& have_vertices,
                    bool& have_faces) {
  const bool is_vertex = e.name == "vertex", is_face = e.name == "face";
  // A second one would replace the vertices its faces or stop reasons were read against.
  if ((is_vertex && have_vertices) || (is_face && have_faces))
    return bad_header("a second " + e.name + " element");
  const Columns c = columns(e);
  if (is_vertex) {
    if (c.x < 0 || c.y < 0 || c.z < 0) return bad_header("vertex element lacks x, y or z");
    r.mesh.vertices.resize(e.count);
    if (c.stop >= 0) r.stop.resize(e.count);
    have_vertices = true;
  }
  if (is_face) {
    if (c.indices < 0) return bad_header("face element lacks vertex_indices");
    have_faces = true;
  }
  std::vector<double> list;
  for (std::size_t n = 0; n < e.count; ++n)
    for (int p = 0; p < static_cast<int>(e.properties.size()); ++p) {
      const Property& prop = e.properties[p];
      Failed f;
      double value = 0.0;
      if (prop.is_list)
        f = read_list(src, prop, e, n, is_face && p == c.indices, list, r.mesh);
      else if (!src.read(prop.type, &value))
        f = Failure{MeshIoError::Code::Truncated, "truncated element " + e.name};
      else if (is_vertex)
        f = store_vertex_value(c, p, n, value, r);
      if (f) return f;
    }
  return std::nullopt;
}

}  // namespace

std::optional<MeshIoError> write_ply(const Mesh& mesh, const std::filesystem::path& path) {
  return write_ply_impl(mesh, nullptr, path);
}

std::optional<MeshIoError> write_balloon_ply(const Mesh& mesh, const std::vector<StopReason>& stop,
                                             const std::filesystem::path& path) {
  if (stop.size() != mesh.vertices.size())
    throw std::invalid_argument("write_balloon_ply: stop.size() != mesh.vertices.size()");
  return write_ply_impl(mesh, &stop, path);
}

std::optional<MeshIoError> write_stl(const Mesh& mesh, const std::filesystem::path& path) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) return io_error(MeshIoError::Code::OpenFailed, path, "cannot open for writing");
  std::string buf(80, '\0');
  const char title[] = "SPACE=LPS sonomesh binary STL, mm";  // Slicer reads the leading SPACE=
  std::memcpy(buf.data(), title, sizeof(title) - 1);
  put(buf, static_cast<std::uint32_t>(mesh.triangles.size()));
  for (const auto& t : mesh.triangles) {
    const Vec3f &a = mesh.vertices[t[0]], &b = mesh.vertices[t[1]], &c = mesh.vertices[t[2]];
    Vec3f n = (b - a).cross(c - a);
    n = n.norm() > 0.0f ? Vec3f(n.normalized()) : Vec3f::Zero();
    for (const Vec3f* p : std::initializer_list<const Vec3f*>{&n, &a, &b, &c})
      for (int i = 0; i < 3; ++i) put(buf, (*p)[i]);
    put(buf, std::uint16_t{0});
  }
  out.write(buf.data(), std::streamsize(buf.size()));
  return finish(out, path);
}

std::optional<MeshIoError> write_obj(const Mesh& mesh, const std::filesystem::path& path) {
  std::ofstream out(path, std::ios::trunc);
  if (!out) return io_error(MeshIoError::Code::OpenFailed, path, "cannot open for writing");
  std::ostringstream s;
  s.precision(9);
  s << "# SPACE=LPS\n# sonomesh mesh, mm\n";
  for (const auto& v : mesh.vertices) s << "v " << v.x() << ' ' << v.y() << ' ' << v.z() << '\n';
  for (const auto& t : mesh.triangles)
    s << "f " << t[0] + 1 << ' ' << t[1] + 1 << ' ' << t[2] + 1 << '\n';
  out << s.str();
  return finish(out, path);
}

std::optional<MeshIoError> write_mesh(const Mesh& mesh, const std::filesystem::path& path) {
  const auto ext = path.extension().string();
  if (ext == ".ply" || ext == ".PLY") return write_ply(mesh, path);
  if (ext == ".stl" || ext == ".STL") return write_stl(mesh, path);
  if (ext == ".obj" || ext == ".OBJ") return write_obj(mesh, path);
  return io_error(MeshIoError::Code::Unsupported, path,
                  "unknown mesh extension (want .ply, .stl or .obj)");
}

// The fewest bytes one item of `e` can take: a binary property its type's size (a list at least its
// count), an ascii value a character and a separator.
std::uintmax_t min_item_bytes(const Element& e, bool ascii) {
  std::uintmax_t bytes = 0;
  for (const Property& p : e.properties)
    bytes += ascii ? 2 : static_cast<std::uintmax_t>(type_size(p.is_list ? p.count_type : p.type));
  return std::max<std::uintmax_t>(bytes, 1);
}

// The element counts against what is left of the file, before anything is allocated for them (a
// header claiming 5·10¹⁶ vertices made read_element allocate that many; found by fuzz_ply).
Failed check_counts(std::istream& in, bool ascii, const std::vector<Element>& elements) {
  const auto here = in.tellg();
  in.seekg(0, std::ios::end);
  const auto end = in.tellg();
  in.seekg(here);
  if (here < 0 || end < here) return Failure{MeshIoError::Code::Truncated, "cannot size the file"};
  // An ascii file's last value may lack its separator: one byte of slack.
  std::uintmax_t left = static_cast<std::uintmax_t>(end - here) + (ascii ? 1 : 0);
  for (const Element& e : elements) {
    const std::uintmax_t item = min_item_bytes(e, ascii);
    if (e.count > left / item)
      return Failure{MeshIoError::Code::Truncated,
                     "element " + e.name + " claims " + std::to_string(e.count) +
                         " items, more than the " + std::to_string(left) + " bytes left hold"};
    left -= e.count * item;
  }
  return std::nullopt;
}

MeshReadResult read_ply(const std::filesystem::path& path) {
  MeshReadResult r;
  auto fail = [&](MeshIoError::Code code, const std::string& what) {
    r.error = io_error(code, path, what);
    r.mesh = {};
    r.stop.clear();
    return r;
  };
  std::ifstream in(path, std::ios::binary);
  if (!in) return fail(MeshIoError::Code::OpenFailed, "cannot open");
  std::string line;
  if (!std::getline(in, line) || line != "ply")
    return fail(MeshIoError::Code::BadHeader, "not a PLY file");
  bool ascii = false;
  std::vector<Element> elements;
  if (Failed f = read_header(in, ascii, elements)) return fail(f->code, f->what);
  if (Failed f = check_counts(in, ascii, elements)) return fail(f->code, f->what);
  Source src(in, ascii);
  bool have_vertices = false, have_faces = false;
  for (const Element& e : elements)
    if (Failed f = read_element(src, e, r, have_vertices, have_faces))
      return fail(f->code, f->what);
  if (!have_vertices || !have_faces)
    return fail(MeshIoError::Code::BadHeader, "needs vertex and face elements");
  return r;
}

}  // namespace sonomesh::mesh
