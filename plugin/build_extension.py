#!/usr/bin/env python3
"""Build the Blender extension zip: dist/photongrid-<version>.zip.

    python3 plugin/build_extension.py [--output-dir DIR] [--blender PATH | --no-blender]

With a Blender binary (``--blender``, ``$BLENDER`` or ``blender`` on PATH) this runs Blender's own
``blender --command extension build``, which also validates the manifest. Without one, but with
Blender as a Python module (``pip install bpy``), it runs the same tool from that module
(``bl_pkg/cli/blender_ext.py build``). With neither it writes the same layout with zipfile: the
manifest and the add-on's files at the root of the zip.
"""

import argparse
import glob
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import zipfile

HERE = os.path.dirname(os.path.abspath(__file__))
SOURCE = os.path.join(HERE, "blender", "photongrid")
REPO = os.path.dirname(HERE)
EXCLUDE_DIRS = {"__pycache__"}
EXCLUDE_SUFFIXES = (".pyc", ".pyo", ".blend1", "~")


def manifest():
    path = os.path.join(SOURCE, "blender_manifest.toml")
    with open(path, "rb") as f:
        data = f.read()
    try:
        import tomllib

        return tomllib.loads(data.decode("utf-8"))
    except ImportError:  # Python < 3.11: the two keys needed, read plainly
        text = data.decode("utf-8")
        return {k: re.search(rf'^{k}\s*=\s*"([^"]+)"', text, re.M).group(1) for k in ("id", "version")}


def files():
    for root, dirs, names in os.walk(SOURCE):
        dirs[:] = sorted(d for d in dirs if d not in EXCLUDE_DIRS and not d.startswith("."))
        for name in sorted(names):
            if name.startswith(".") or name.endswith(EXCLUDE_SUFFIXES):
                continue
            full = os.path.join(root, name)
            yield full, os.path.relpath(full, SOURCE).replace(os.sep, "/")


def build_with_zipfile(out_path):
    with zipfile.ZipFile(out_path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for full, arc in files():
            info = zipfile.ZipInfo(arc, date_time=(2024, 1, 1, 0, 0, 0))  # reproducible
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            with open(full, "rb") as f:
                z.writestr(info, f.read())


def build_with_blender(blender, out_dir):
    cmd = [blender, "--factory-startup", "--command", "extension", "build",
           "--source-dir", SOURCE, "--output-dir", out_dir]
    print("+", " ".join(cmd))
    subprocess.run(cmd, check=True)


def bundled_extension_tool():
    """blender_ext.py from an installed bpy module, found without importing bpy; or None."""
    try:
        spec = importlib.util.find_spec("bpy")
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.origin:
        return None
    pattern = os.path.join(os.path.dirname(spec.origin), "*", "scripts", "addons_core", "bl_pkg", "cli",
                           "blender_ext.py")
    found = sorted(glob.glob(pattern))
    return found[-1] if found else None


def build_with_tool(tool, out_dir):
    cmd = [sys.executable, tool, "build", "--source-dir", SOURCE, "--output-dir", out_dir]
    print("+", " ".join(cmd))
    subprocess.run(cmd, check=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--output-dir", default=os.path.join(REPO, "dist"))
    ap.add_argument("--blender", default=os.environ.get("BLENDER") or shutil.which("blender"),
                    help="Blender binary (default: $BLENDER, then blender on PATH)")
    ap.add_argument("--no-blender", action="store_true",
                    help="build with zipfile even if Blender or the bpy module is there")
    args = ap.parse_args()

    m = manifest()
    out_dir = os.path.abspath(args.output_dir)
    os.makedirs(out_dir, exist_ok=True)
    out_path = os.path.join(out_dir, f"{m['id']}-{m['version']}.zip")
    if os.path.exists(out_path):
        os.remove(out_path)
    tool = None if args.no_blender else bundled_extension_tool()
    if args.blender and not args.no_blender:
        build_with_blender(args.blender, out_dir)
    elif tool:
        build_with_tool(tool, out_dir)
    else:
        build_with_zipfile(out_path)
    if not os.path.isfile(out_path):
        sys.exit(f"error: {out_path} was not written")
    with zipfile.ZipFile(out_path) as z:
        names = z.namelist()
    if "blender_manifest.toml" not in names or "__init__.py" not in names:
        sys.exit(f"error: {out_path} lacks blender_manifest.toml or __init__.py at its root: {names}")
    print(out_path)


if __name__ == "__main__":
    main()
