#!/usr/bin/env python3
"""Do other programs read our triangle soups? (docs/formats.md)

    python3 scripts/check_interop.py SCENE.ply SCENE.glb FACES [--require-all]

Loads the PLY and the GLB (written from the same scene by write_triangle_ply
and write_triangle_glb) with three independent readers, each checking the face
count and, on a few faces, the colours against the PLY's float face properties
(the lossless source, parsed here with the standard library):

  trimesh  (Python package; process=False): vertex colours, bytes
  assimp   (assimp-utils: `assimp info -r`, colours from `assimp dump`)
  blender  (background mode, scripts/check_interop_blender.py): colour attribute

PLY colours are display (sRGB) values, quantised to bytes on the vertices;
GLB COLOR_0 is linear (sRGB -> linear), alpha = opacity. One line per reader
and file: OK, MISMATCH (with numbers) or UNAVAILABLE (with why). Exit status 1
on any mismatch, and with --require-all also on an unavailable reader.
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


def read_flat_ply(path):
    """Our PLY layout (both the current one and the older one without vertex
    colours): returns the face count and each face's (r, g, b, opacity)."""
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
    vertex_size = {3: 12, 7: 16}.get(len(props.get("vertex", [])))
    want_face = ["list uchar int vertex_indices", "float red", "float green", "float blue", "float opacity",
                 "float sigma"]
    if vertex_size is None or props.get("face") != want_face:
        raise SystemExit(f"{path}: not the FLAT triangle PLY layout (docs/formats.md)")
    at = end + len(b"end_header\n") + counts["vertex"] * vertex_size
    colours = []
    for _ in range(counts["face"]):
        n = data[at]
        if n != 3:
            raise SystemExit(f"{path}: a face with {n} vertices")
        r, g, b, o, _sigma = struct.unpack_from("<5f", data, at + 13)
        colours.append((r, g, b, o))
        at += 33
    return counts["face"], colours


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

def trimesh_read(path, kind, sample):
    try:
        import numpy  # noqa: F401
        import trimesh
    except ImportError as e:
        raise Unavailable(f"python package not importable by {sys.executable}: {e} (pip install trimesh, or run "
                          f"this script with the project's venv: ~/.cache/flat/venv/bin/python3)")
    loaded = trimesh.load(path, process=False)
    meshes = list(loaded.geometry.values()) if isinstance(loaded, trimesh.Scene) else [loaded]
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

def assimp_read(path, kind, sample, face_count):
    exe = shutil.which("assimp")
    if not exe:
        raise Unavailable("no assimp on PATH (Debian package assimp-utils)")
    info = subprocess.run([exe, "info", path, "-r"], capture_output=True, text=True, timeout=600)
    m = re.search(r"^Faces:\s+(\d+)", info.stdout, re.M)
    if info.returncode != 0 or not m:
        raise Mismatch(f"assimp info failed (status {info.returncode}): {(info.stdout + info.stderr)[-300:]}")
    faces = int(m.group(1))
    colours = {}
    exact = kind == "GLB"  # floats as stored
    if face_count <= MAX_COLOUR_CHECK_FACES:
        with tempfile.TemporaryDirectory() as tmp:
            out = os.path.join(tmp, "dump.xml")
            dump = subprocess.run([exe, "dump", path, out], capture_output=True, text=True, timeout=600)
            if dump.returncode != 0 or not os.path.exists(out):
                raise Mismatch(f"assimp dump failed (status {dump.returncode}): {dump.stderr[-300:]}")
            with open(out) as f:
                xml = f.read()
        # First mesh: its faces and its first colour set.
        mesh = xml[xml.find("<Mesh"):]
        face_list = [list(map(int, body.split())) for body in re.findall(r"<Face num=\"\d+\">(.*?)</Face>", mesh, re.S)]
        cm = re.search(r"<Colors num=\"\d+\" set=\"0\"[^>]*>(.*?)</Colors>", mesh, re.S)
        if cm:
            values = list(map(float, cm.group(1).split()))
            per_vertex = [values[i:i + 4] for i in range(0, len(values), 4)]
            for f in sample:
                if f < len(face_list):
                    colours[f] = [per_vertex[v] for v in face_list[f]]
    return faces, colours, exact


# --- Blender ---------------------------------------------------------------

def blender_read(path, kind, sample):
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
    return out["faces"], {int(k): v for k, v in out.get("colours_srgb", {}).items()}, False


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
    parser.add_argument("ply", help="triangle PLY written by write_triangle_ply")
    parser.add_argument("glb", help="GLB of the same scene written by write_triangle_glb ('-': none)")
    parser.add_argument("faces", type=int, help="expected number of faces (triangles)")
    parser.add_argument("--require-all", action="store_true", help="an unavailable reader is a failure too")
    args = parser.parse_args()

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
            try:
                faces, colours, exact = read(path, kind)
                if faces != args.faces:
                    raise Mismatch(f"{faces} faces, expected {args.faces}")
                if args.faces <= MAX_COLOUR_CHECK_FACES or colours:
                    checked = compare(colours, expected, 1e-5 if exact else tolerance, what)
                    print(f"{name:9} {kind}  OK {faces} faces; {what} of {checked} faces match")
                else:
                    print(f"{name:9} {kind}  OK {faces} faces; colours not checked (large file)")
            except Unavailable as e:
                print(f"{name:9} {kind}  UNAVAILABLE {e}")
                failed |= args.require_all
            except Mismatch as e:
                print(f"{name:9} {kind}  MISMATCH {e}")
                failed = True
            except Exception as e:  # a reader that crashes on our file is a mismatch
                print(f"{name:9} {kind}  MISMATCH {type(e).__name__}: {e}")
                failed = True
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
