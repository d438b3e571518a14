#!/usr/bin/env python3
"""Do other programs read our triangle soups and opaque meshes? (docs/formats.md)

    python3 scripts/check_interop.py SCENE.ply SCENE.glb FACES [--require-all]
    python3 scripts/check_interop.py --mesh MESH.glb MESH.ply MESH.obj [--require-all]

Loads the PLY and the GLB (written from the same scene by write_triangle_ply
and write_triangle_glb) with three independent readers, each checking the face
count and, on a few faces, the colours against the PLY's float face properties
(the lossless source, parsed here with the standard library):

  trimesh  (Python package; process=False): vertex colours, bytes
  assimp   (assimp-utils: `assimp info -r`, colours from `assimp dump`)
  blender  (background mode, scripts/check_interop_blender.py): colour attribute

PLY colours are display (sRGB) values, quantised to bytes on the vertices;
GLB COLOR_0 is linear (sRGB -> linear), alpha = opacity.

With --mesh: the opaque indexed mesh (write_mesh_glb / _ply / _obj, shared
vertices, colours on the vertices). The expected vertex count V, face count F
and vertex colours (bytes) come from the PLY, parsed here; each reader reads
all three files and is checked for V vertices, F faces and, on a few faces,
each corner's colour: PLY bytes; OBJ floats with 4 decimals; GLB COLOR_0
linear, compared with the PLY bytes after sRGB -> linear (1/255, or half a
byte's step where the curve is steeper). GLB may be '-' (built without
tinygltf).

One line per reader and file: OK, MISMATCH (with numbers) or UNAVAILABLE
(with why). Exit status 1 on any mismatch, and with --require-all also on an
unavailable reader (or a GLB given as '-').
Runs with any python3; trimesh is imported only when that reader runs. When
the interpreter it was started with has no trimesh and the project's venv
(~/.cache/flat/venv/bin/python3, made by scripts/install_deps.sh; or
$FLAT_PYTHON) has it, the script runs itself again with that one and says so.
"""
import argparse
import json
import os
import re
import shutil
import struct
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
BYTE = 1.0 / 255.0
MAX_COLOUR_CHECK_FACES = 100000  # assimp's XML dump of larger files is too slow to parse


class Unavailable(Exception):
    pass


class Mismatch(Exception):
    pass


def srgb_to_linear(s):
    return s / 12.92 if s <= 0.04045 else ((s + 0.055) / 1.055) ** 2.4


def clamp01(x):
    return min(1.0, max(0.0, x))


def read_ply_header(path):
    """(file bytes, offset of the body, {element: count}, {element: [property]})."""
    with open(path, "rb") as f:
        data = f.read()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise SystemExit(f"{path}: not a PLY file")
    header = data[:end].decode("ascii").splitlines()
    counts, props, element = {}, {}, None
    for line in header:
        words = line.split()
        if words[:1] == ["element"]:
            element = words[1]
            counts[element] = int(words[2])
            props[element] = []
        elif words[:1] == ["property"]:
            props[element].append(" ".join(words[1:]))
    if "binary_little_endian" not in data[:end].decode("ascii"):
        raise SystemExit(f"{path}: not binary little-endian (not written by FLAT-C++?)")
    return data, end + len(b"end_header\n"), counts, props


def read_flat_ply(path):
    """Our PLY layout (both the current one and the older one without vertex
    colours): returns the face count and each face's (r, g, b, opacity)."""
    data, body, counts, props = read_ply_header(path)
    vertex_size = {3: 12, 7: 16}.get(len(props.get("vertex", [])))
    want_face = ["list uchar int vertex_indices", "float red", "float green", "float blue", "float opacity",
                 "float sigma"]
    if vertex_size is None or props.get("face") != want_face:
        raise SystemExit(f"{path}: not the FLAT triangle PLY layout (docs/formats.md)")
    at = body + counts["vertex"] * vertex_size
    colours = []
    for _ in range(counts["face"]):
        n = data[at]
        if n != 3:
            raise SystemExit(f"{path}: a face with {n} vertices")
        r, g, b, o, _sigma = struct.unpack_from("<5f", data, at + 13)
        colours.append((r, g, b, o))
        at += 33
    return counts["face"], colours


def read_mesh_ply(path):
    """Our opaque mesh PLY (write_mesh_ply): returns each vertex's (r, g, b)
    bytes and each face's three vertex indices."""
    data, body, counts, props = read_ply_header(path)
    if (props.get("vertex") != ["float x", "float y", "float z", "uchar red", "uchar green", "uchar blue"]
            or props.get("face") != ["list uchar int vertex_indices"]):
        raise SystemExit(f"{path}: not the FLAT opaque mesh PLY layout (docs/formats.md)")
    nv, nf = counts["vertex"], counts["face"]
    if len(data) != body + 15 * nv + 13 * nf:
        raise SystemExit(f"{path}: {len(data) - body} bytes after the header, expected {15 * nv + 13 * nf}")
    colours = [tuple(data[at + 12:at + 15]) for at in range(body, body + 15 * nv, 15)]
    faces = []
    for at in range(body + 15 * nv, len(data), 13):
        if data[at] != 3:
            raise SystemExit(f"{path}: a face with {data[at]} vertices")
        face = struct.unpack_from("<3i", data, at + 1)
        if not all(0 <= v < nv for v in face):
            raise SystemExit(f"{path}: face {len(faces)} has vertex indices {face}, {nv} vertices")
        faces.append(face)
    return colours, faces


def sample_faces(n):
    if n <= 0:
        return []
    picks = {0, n - 1, n // 2}
    picks.update(range(0, n, max(1, n // 5)))
    return sorted(picks)


def compare(got, expected, tolerance, what):
    """got/expected: {face: [rgba per corner] or rgba}; raises Mismatch."""
    worst, where = 0.0, None
    for face, exp in expected.items():
        corners = got.get(face)
        if corners is None:
            raise Mismatch(f"{what}: no colour for face {face}")
        for corner in corners:
            for c in range(4):
                err = abs(corner[c] - exp[c])
                if err > worst:
                    worst, where = err, (face, corner, exp)
    if worst > tolerance:
        face, corner, exp = where
        raise Mismatch(f"{what}: face {face} has {[round(x, 4) for x in corner]}, expected "
                       f"{[round(x, 4) for x in exp]} (|error| {worst:.4f} > {tolerance:.4f})")
    return len(expected)


# --- trimesh ---------------------------------------------------------------

def trimesh_load(path):
    """The meshes trimesh reads from path (process=False: as stored, no merging)."""
    try:
        import numpy  # noqa: F401
        import trimesh
    except ImportError as e:
        raise Unavailable(f"python package not importable by {sys.executable}: {e} (pip install trimesh, or run "
                          f"this script with the project's venv: ~/.cache/flat/venv/bin/python3)")
    loaded = trimesh.load(path, process=False)
    return list(loaded.geometry.values()) if isinstance(loaded, trimesh.Scene) else [loaded]


def trimesh_read(path, kind, sample):
    meshes = trimesh_load(path)
    faces = sum(len(m.faces) for m in meshes)
    colours, exact = {}, False
    if meshes:
        m = meshes[0]
        if m.visual.kind == "vertex":  # vertex colours as bytes (PLY; GLB without material)
            per_vertex = m.visual.vertex_colors / 255.0
        else:  # a GLB with a material: trimesh keeps COLOR_0 as given (floats)
            per_vertex = getattr(m.visual, "vertex_attributes", {}).get("color")
            exact = per_vertex is not None and per_vertex.dtype.kind == "f"
        if per_vertex is not None:
            for f in sample:
                if f < len(m.faces):
                    colours[f] = [[float(x) for x in per_vertex[v]] for v in m.faces[f]]
    return faces, colours, exact


# --- assimp ----------------------------------------------------------------

def assimp_exe():
    exe = shutil.which("assimp")
    if not exe:
        raise Unavailable("no assimp on PATH (Debian package assimp-utils)")
    return exe


def assimp_info(exe, path):
    """(faces, vertices) as `assimp info -r` (raw: no post-processing) counts them."""
    info = subprocess.run([exe, "info", path, "-r"], capture_output=True, text=True, timeout=600)
    m = re.search(r"^Faces:\s+(\d+)", info.stdout, re.M)
    v = re.search(r"^Vertices:\s+(\d+)", info.stdout, re.M)
    if info.returncode != 0 or not m:
        raise Mismatch(f"assimp info failed (status {info.returncode}): {(info.stdout + info.stderr)[-300:]}")
    return int(m.group(1)), int(v.group(1)) if v else None


def assimp_dump(exe, path):
    """The first mesh of `assimp dump`: its faces (vertex indices) and its
    first colour set (RGBA per vertex; None without one)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "dump.xml")
        dump = subprocess.run([exe, "dump", path, out], capture_output=True, text=True, timeout=600)
        if dump.returncode != 0 or not os.path.exists(out):
            raise Mismatch(f"assimp dump failed (status {dump.returncode}): {dump.stderr[-300:]}")
        with open(out) as f:
            xml = f.read()
    mesh = xml[xml.find("<Mesh"):]
    face_list = [list(map(int, body.split())) for body in re.findall(r"<Face num=\"\d+\">(.*?)</Face>", mesh, re.S)]
    cm = re.search(r"<Colors num=\"\d+\" set=\"0\"[^>]*>(.*?)</Colors>", mesh, re.S)
    per_vertex = None
    if cm:
        values = list(map(float, cm.group(1).split()))
        per_vertex = [values[i:i + 4] for i in range(0, len(values), 4)]
    return face_list, per_vertex


def assimp_read(path, kind, sample, face_count):
    exe = assimp_exe()
    faces, _ = assimp_info(exe, path)
    colours = {}
    exact = kind == "GLB"  # floats as stored
    if face_count <= MAX_COLOUR_CHECK_FACES:
        face_list, per_vertex = assimp_dump(exe, path)
        if per_vertex is not None:
            for f in sample:
                if f < len(face_list):
                    colours[f] = [per_vertex[v] for v in face_list[f]]
    return faces, colours, exact


# --- Blender ---------------------------------------------------------------

def blender_run(path, sample):
    """check_interop_blender.py's result for path: faces, vertices, colour
    attributes and the sampled faces' corner colours as sRGB."""
    exe = shutil.which("blender")
    if not exe:
        raise Unavailable("no blender on PATH (Debian package blender)")
    helper = os.path.join(HERE, "check_interop_blender.py")
    with tempfile.TemporaryDirectory() as tmp:
        result = os.path.join(tmp, "result.json")
        # Debian's blender embeds the system Python and finds its home through the
        # `python3` on PATH: put blender's own folder first so that a pyenv or venv
        # python3 earlier on PATH (without numpy) is not taken for it.
        env = dict(os.environ, PATH=os.path.dirname(exe) + os.pathsep + os.environ.get("PATH", ""))
        run = subprocess.run([exe, "--background", "--factory-startup", "--python-exit-code", "3",
                              "--python", helper, "--", path, result] + [str(f) for f in sample],
                             capture_output=True, text=True, timeout=900, env=env)
        if run.returncode != 0 or not os.path.exists(result):
            raise Mismatch(f"blender failed (status {run.returncode}): {(run.stdout + run.stderr)[-400:]}")
        with open(result) as f:
            out = json.load(f)
    if out.get("colour_attributes") == []:
        raise Mismatch("blender: the imported mesh has no colour attribute")
    return out


def blender_read(path, kind, sample):
    out = blender_run(path, sample)
    return out["faces"], {int(k): v for k, v in out.get("colours_srgb", {}).items()}, False


# --- opaque mesh mode (--mesh) ----------------------------------------------
# Each reader returns (vertices, faces, {sampled face: [colour per corner]});
# colours are in the space main_mesh's table says (display or linear), RGB(A).

def corner_colours(per_vertex, face_list, sample):
    return {f: [list(per_vertex[v]) for v in face_list[f]] for f in sample if f < len(face_list)}


def trimesh_mesh_read(path, kind, sample):
    meshes = trimesh_load(path)
    vertices, faces = sum(len(m.vertices) for m in meshes), sum(len(m.faces) for m in meshes)
    colours = {}
    if meshes:
        m = meshes[0]
        # GLB with a material: COLOR_0 kept as stored (linear floats) in
        # vertex_attributes; PLY and OBJ: vertex colours as bytes (the OBJ's
        # floats rounded to bytes by trimesh).
        per_vertex = getattr(m.visual, "vertex_attributes", {}).get("color")
        if per_vertex is None and m.visual.kind == "vertex":
            per_vertex = m.visual.vertex_colors / 255.0
        if per_vertex is not None:
            colours = corner_colours(per_vertex.tolist(), m.faces.tolist(), sample)
    return vertices, faces, colours


def assimp_mesh_read(path, kind, sample, face_count):
    exe = assimp_exe()
    faces, vertices = assimp_info(exe, path)
    colours = {}
    if face_count <= MAX_COLOUR_CHECK_FACES:
        face_list, per_vertex = assimp_dump(exe, path)
        if per_vertex is not None:
            colours = corner_colours(per_vertex, face_list, sample)
    return vertices, faces, colours


def blender_mesh_read(path, kind, sample):
    out = blender_run(path, sample)
    return out["vertices"], out["faces"], {int(k): v for k, v in out.get("colours_srgb", {}).items()}


def compare_corners(got, expected, what):
    """got: {face: [colour per corner]}; expected: {face: [[(value, tolerance)
    for r, g, b] per corner]}. Compares r, g, b (the opaque mesh has no alpha;
    assimp fills a VEC3 COLOR_0's alpha with 0). Raises Mismatch; returns the
    number of faces checked and the worst error relative to its tolerance."""
    worst, where = 0.0, None
    for face, exp in expected.items():
        corners = got.get(face)
        if corners is None or len(corners) != len(exp):
            raise Mismatch(f"{what}: face {face} has {'no colour' if corners is None else f'{len(corners)} corners'}")
        for corner, exp_corner in zip(corners, exp):
            for c, (value, tolerance) in enumerate(exp_corner):
                ratio = abs(corner[c] - value) / tolerance
                if ratio > worst:
                    worst, where = ratio, (face, corner, exp_corner, tolerance)
    if worst > 1.0:
        face, corner, exp_corner, tolerance = where
        raise Mismatch(f"{what}: face {face} has a corner {[round(x, 4) for x in corner[:3]]}, expected "
                       f"{[round(v, 4) for v, _ in exp_corner]} (|error| {worst * tolerance:.4f} > {tolerance:.4f})")
    return len(expected), worst


def report(name, kind, check, require_all):
    """Runs check() (the OK text, or Unavailable / Mismatch) and prints one
    line; returns whether the run has failed because of it."""
    try:
        print(f"{name:9} {kind}  OK {check()}")
        return False
    except Unavailable as e:
        print(f"{name:9} {kind}  UNAVAILABLE {e}")
        return require_all
    except Mismatch as e:
        print(f"{name:9} {kind}  MISMATCH {e}")
        return True
    except Exception as e:  # a reader that crashes on our file is a mismatch
        print(f"{name:9} {kind}  MISMATCH {type(e).__name__}: {e}")
        return True


def main_mesh(args):
    glb, ply, obj = args.mesh
    for path, ext in ((glb, ".glb"), (ply, ".ply"), (obj, ".obj")):
        if path == "-" and ext == ".glb":
            continue
        if not path.lower().endswith(ext):
            raise SystemExit(f"--mesh takes MESH.glb MESH.ply MESH.obj in that order; {path} is not a {ext} file")
        if not os.path.isfile(path):
            raise SystemExit(f"{path}: no such file")
    vertex_bytes, face_list = read_mesh_ply(ply)
    nv, nf = len(vertex_bytes), len(face_list)
    print(f"{'reference':9} PLY  {nv} vertices, {nf} faces (parsed here)")
    sample = sample_faces(nf)

    def display(tolerance):  # byte / 255: PLY bytes, OBJ floats, Blender's sRGB colours
        return {f: [[(b / 255, tolerance) for b in vertex_bytes[v]] for v in face_list[f]] for f in sample}

    def linear_value(b):
        # GLB COLOR_0 = sRGB -> linear of the unrounded colour, which is within
        # half a byte of the PLY's: 1/255 in linear, or that half byte's step
        # where the curve is steeper (bright colours; up to ~1.15/255).
        s = b / 255
        return srgb_to_linear(s), max(BYTE, srgb_to_linear(s + 0.51 * BYTE) - srgb_to_linear(s))

    linear = {f: [[linear_value(b) for b in vertex_bytes[v]] for v in face_list[f]] for f in sample}
    obj_floats = 0.5 * BYTE + 1e-4  # the OBJ's 4 decimals of the colour the PLY rounds to a byte
    # (reader, read function, {kind: (expected colours, what the numbers are)})
    readers = [
        ("trimesh", lambda p, k: trimesh_mesh_read(p, k, sample),
         {"PLY": (display(0.51 * BYTE), "vertex colour bytes"),
          # trimesh rounds the OBJ's 4-decimal floats to bytes: can be one off the PLY's.
          "OBJ": (display(1.01 * BYTE), "vertex colour bytes"),
          "GLB": (linear, "linear COLOR_0")}),
        ("assimp", lambda p, k: assimp_mesh_read(p, k, sample, nf),
         {"PLY": (display(0.51 * BYTE), "vertex colours"),
          "OBJ": (display(obj_floats), "vertex colours"),
          "GLB": (linear, "linear COLOR_0")}),
        ("blender", lambda p, k: blender_mesh_read(p, k, sample),
         {"PLY": (display(0.51 * BYTE), "colour attribute (sRGB)"),
          "OBJ": (display(obj_floats), "colour attribute (sRGB)"),
          # Blender's glTF importer stores linear COLOR_0 as sRGB bytes: one
          # off the PLY's where the colour sits on a half byte.
          "GLB": (display(1.01 * BYTE), "colour attribute (sRGB)")}),
    ]
    files = ([("GLB", glb)] if glb != "-" else []) + [("PLY", ply), ("OBJ", obj)]
    failed = False
    if glb == "-":
        print(f"{'all':9} GLB  UNAVAILABLE no GLB given")
        failed = args.require_all
    for name, read, expectations in readers:
        for kind, path in files:
            expected, what = expectations[kind]

            def check():
                vertices, faces, colours = read(path, kind)
                counts = f"{vertices} vertices, {faces} faces"
                # assimp's OBJ importer makes one vertex per face corner (OBJ
                # faces may index positions, uvs and normals separately) and
                # `assimp info -r` joins none: there 3 F vertices is right too.
                per_corner = (name, kind) == ("assimp", "OBJ")
                note = ""
                if per_corner and vertices == 3 * nf != nv:
                    note = f" (one per face corner: assimp's OBJ importer shares none; the file has {nv})"
                if faces != nf or (vertices != nv and not note):
                    alternative = f" (or {3 * nf}, one per face corner)" if per_corner else ""
                    raise Mismatch(f"{counts}, expected {nv}{alternative} vertices, {nf} faces")
                if nf <= MAX_COLOUR_CHECK_FACES or colours:
                    checked, worst = compare_corners(colours, expected, what)
                    return (f"{counts}{note}; {what} of {checked} faces match "
                            f"(worst {100 * worst:.0f}% of the tolerance)")
                else:
                    return f"{counts}{note}; colours not checked (large file)"

            failed |= report(name, kind, check, args.require_all)
    return 1 if failed else 0


def project_python():
    """The project's venv python (or $FLAT_PYTHON) when it is another interpreter than this one."""
    candidate = os.environ.get("FLAT_PYTHON") or os.path.expanduser("~/.cache/flat/venv/bin/python3")
    # Not realpath: a venv's python is a link to the interpreter it was made
    # from, which may be the very one running now, without the venv's packages.
    if not os.path.isfile(candidate) or os.path.abspath(candidate) == os.path.abspath(sys.executable):
        return None
    return candidate


def reexec_with_trimesh():
    """The system python often lacks trimesh while the project's venv has it: use that one."""
    try:
        import trimesh  # noqa: F401
        return
    except ImportError:
        pass
    if os.environ.get("FLAT_INTEROP_REEXEC"):
        return  # already re-run once: report trimesh as unavailable
    other = project_python()
    if other is None:
        return
    probe = subprocess.run([other, "-c", "import trimesh"], capture_output=True)
    if probe.returncode != 0:
        return
    print(f"check_interop: {sys.executable} has no trimesh; running with {other}", flush=True)
    os.environ["FLAT_INTEROP_REEXEC"] = "1"
    os.execv(other, [other, os.path.abspath(__file__)] + sys.argv[1:])


def main():
    reexec_with_trimesh()
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("ply", nargs="?", help="triangle PLY written by write_triangle_ply")
    parser.add_argument("glb", nargs="?", help="GLB of the same scene written by write_triangle_glb ('-': none)")
    parser.add_argument("faces", nargs="?", type=int, help="expected number of faces (triangles)")
    parser.add_argument("--mesh", nargs=3, metavar=("MESH.glb", "MESH.ply", "MESH.obj"),
                        help="check an opaque mesh (write_mesh_glb/_ply/_obj) instead; GLB '-': none")
    parser.add_argument("--require-all", action="store_true", help="an unavailable reader is a failure too")
    args = parser.parse_args()
    if args.mesh:
        if args.ply is not None:
            parser.error("--mesh takes no other files")
        return main_mesh(args)
    if args.faces is None:
        parser.error("the following arguments are required: ply, glb, faces (or --mesh)")
    return main_soup(args)


def main_soup(args):
    ply_faces, face_colours = read_flat_ply(args.ply)
    if ply_faces != args.faces:
        print(f"{'reference':9} PLY  MISMATCH {ply_faces} faces in the file's header, expected {args.faces}")
        return 1
    sample = sample_faces(args.faces)
    # Expected colours of the sampled faces, in each reader's space.
    display = {f: [clamp01(x) for x in face_colours[f]] for f in sample}
    byte_display = {f: [round(255 * x) / 255 for x in display[f]] for f in sample}
    linear = {f: [srgb_to_linear(x) for x in display[f][:3]] + [display[f][3]] for f in sample}

    files = [("PLY", args.ply)] + ([("GLB", args.glb)] if args.glb != "-" else [])
    # (reader, read function, {kind: (expected colours, tolerance, what the numbers are)})
    # Readers that hand back the stored floats (exact) are held to float precision.
    readers = [
        ("trimesh", lambda p, k: trimesh_read(p, k, sample),
         {"PLY": (byte_display, 0.51 * BYTE, "vertex colour bytes"),
          "GLB": (linear, 1.01 * BYTE, "linear COLOR_0")}),
        ("assimp", lambda p, k: assimp_read(p, k, sample, args.faces),
         {"PLY": (byte_display, 0.51 * BYTE, "vertex colours"),
          "GLB": (linear, 1.01 * BYTE, "linear COLOR_0")}),
        ("blender", lambda p, k: blender_read(p, k, sample),
         {"PLY": (byte_display, 0.51 * BYTE, "colour attribute (sRGB)"),
          "GLB": (display, 1.01 * BYTE, "colour attribute (sRGB)")}),
    ]
    failed = False
    if args.glb == "-":
        print(f"{'all':9} GLB  UNAVAILABLE no GLB given")
        failed = args.require_all
    for name, read, expectations in readers:
        for kind, path in files:
            expected, tolerance, what = expectations[kind]

            def check():
                faces, colours, exact = read(path, kind)
                if faces != args.faces:
                    raise Mismatch(f"{faces} faces, expected {args.faces}")
                if args.faces <= MAX_COLOUR_CHECK_FACES or colours:
                    checked = compare(colours, expected, 1e-5 if exact else tolerance, what)
                    return f"{faces} faces; {what} of {checked} faces match"
                else:
                    return f"{faces} faces; colours not checked (large file)"

            failed |= report(name, kind, check, args.require_all)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
