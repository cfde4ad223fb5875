#!/usr/bin/env python3
"""Build the Blender extension: a platform zip with the renderer inside.

    python3 plugin/build_extension.py [--output-dir DIR] [--binary PATH | --no-binary]
                                      [--blender PATH | --no-blender]

By default this builds the release binary (``cargo build --release --locked``),
copies it (stripped of debug information when ``strip`` is there) into ``bin/`` of a staging
copy of ``plugin/blender/photongrid``, writes its ``settings --schema`` beside it, and packs the
platform zip the Blender way (``--split-platforms``: ``platforms = ["linux-x64"]`` in the
manifest, one zip per platform named ``photongrid-<version>-linux_x64.zip``). Installed from
disk, the add-on finds that binary with nothing to set.

``--binary PATH`` packs an existing binary instead of building one; ``--no-binary`` writes the
pure-Python zip ``photongrid-<version>.zip`` (the binary then comes from the preferences,
``PHOTONGRID_BIN`` or ``PATH``).

Packing uses Blender's own tool, which also validates the manifest: ``blender --command
extension build`` with a Blender binary (``--blender``, ``$BLENDER`` or ``blender`` on PATH),
else the same tool from an installed ``bpy`` module (``bl_pkg/cli/blender_ext.py``), else
zipfile with the same layout (manifest at the root).
"""

import argparse
import glob
import importlib.util
import json
import os
import re
import shutil
import stat
import subprocess
import sys
import tempfile
import zipfile

HERE = os.path.dirname(os.path.abspath(__file__))
SOURCE = os.path.join(HERE, "blender", "photongrid")
REPO = os.path.dirname(HERE)
EXCLUDE_DIRS = {"__pycache__"}
EXCLUDE_SUFFIXES = (".pyc", ".pyo", ".blend1", "~")
PLATFORM = "linux-x64"  # the platform this script builds the binary for


def manifest(source=SOURCE):
    path = os.path.join(source, "blender_manifest.toml")
    with open(path, "rb") as f:
        data = f.read()
    try:
        import tomllib

        return tomllib.loads(data.decode("utf-8"))
    except ImportError:  # Python < 3.11: the keys needed, read plainly
        text = data.decode("utf-8")
        m = {k: re.search(rf'^{k}\s*=\s*"([^"]+)"', text, re.M).group(1) for k in ("id", "version")}
        p = re.search(r"^platforms\s*=\s*\[([^\]]*)\]", text, re.M)
        m["platforms"] = re.findall(r'"([^"]+)"', p.group(1)) if p else []
        return m


def files(source):
    for root, dirs, names in os.walk(source):
        dirs[:] = sorted(d for d in dirs if d not in EXCLUDE_DIRS and not d.startswith("."))
        for name in sorted(names):
            if name.startswith(".") or name.endswith(EXCLUDE_SUFFIXES):
                continue
            full = os.path.join(root, name)
            yield full, os.path.relpath(full, source).replace(os.sep, "/")


def build_with_zipfile(source, out_path, generated_platform=None):
    with zipfile.ZipFile(out_path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for full, arc in files(source):
            info = zipfile.ZipInfo(arc, date_time=(2024, 1, 1, 0, 0, 0))  # reproducible
            info.compress_type = zipfile.ZIP_DEFLATED
            executable = os.stat(full).st_mode & stat.S_IXUSR
            info.external_attr = (0o755 if executable else 0o644) << 16
            with open(full, "rb") as f:
                data = f.read()
            if arc == "blender_manifest.toml" and generated_platform:
                # What Blender's --split-platforms adds to each platform's manifest.
                data += (f'\n\n# BEGIN GENERATED CONTENT.\n[build.generated]\nplatforms = ["{generated_platform}"]\n'
                         "wheels = []\n# END GENERATED CONTENT.\n").encode()
            z.writestr(info, data)


def build_with_blender(blender, source, out_dir, split):
    cmd = [blender, "--factory-startup", "--command", "extension", "build",
           "--source-dir", source, "--output-dir", out_dir] + (["--split-platforms"] if split else [])
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


def build_with_tool(tool, source, out_dir, split):
    cmd = [sys.executable, tool, "build", "--source-dir", source, "--output-dir", out_dir]
    cmd += ["--split-platforms"] if split else []
    print("+", " ".join(cmd))
    subprocess.run(cmd, check=True)


def cargo_build():
    """The release binary of this repository, built (a no-op when up to date)."""
    # The whole workspace, as CI and the README build it: the same features, so a no-op then.
    cmd = ["cargo", "build", "--release", "--locked"]
    print("+", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, cwd=REPO)
    target = os.environ.get("CARGO_TARGET_DIR") or os.path.join(REPO, "target")
    return os.path.join(target, "release", "photongrid")


def stage(binary, staging):
    """A copy of the add-on with ``binary`` in ``bin/`` and its settings schema, and
    ``platforms`` set in the manifest."""
    shutil.copytree(SOURCE, staging, ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "bin",
                                                                    "settings_schema.json"))
    os.makedirs(os.path.join(staging, "bin"))
    dest = os.path.join(staging, "bin", "photongrid")
    shutil.copy2(binary, dest)
    strip = shutil.which("strip")
    if strip:  # the release profile keeps line tables for profiling; the add-on needs none
        subprocess.run([strip, "--strip-debug", dest], check=True)
    os.chmod(dest, 0o755)
    schema = subprocess.run([dest, "settings", "--schema"], check=True, capture_output=True, text=True).stdout
    json.loads(schema)  # a binary that cannot describe its settings is not packed
    with open(os.path.join(staging, "settings_schema.json"), "w", encoding="utf-8") as f:
        f.write(schema)
    path = os.path.join(staging, "blender_manifest.toml")
    with open(path, encoding="utf-8") as f:
        text = f.read()
    line = f'platforms = ["{PLATFORM}"]'
    if re.search(r"^platforms\s*=", text, re.M):
        text = re.sub(r"^platforms\s*=.*$", line, text, flags=re.M)
    else:
        text = text.replace('blender_version_min', line + '\nblender_version_min', 1)
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--output-dir", default=os.path.join(REPO, "dist"))
    ap.add_argument("--binary", help="pack this photongrid binary instead of building one")
    ap.add_argument("--no-binary", action="store_true", help="the pure-Python zip, without a binary")
    ap.add_argument("--blender", default=os.environ.get("BLENDER") or shutil.which("blender"),
                    help="Blender binary (default: $BLENDER, then blender on PATH)")
    ap.add_argument("--no-blender", action="store_true",
                    help="build with zipfile even if Blender or the bpy module is there")
    args = ap.parse_args()

    out_dir = os.path.abspath(args.output_dir)
    os.makedirs(out_dir, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="photongrid-ext-") as tmp:
        source = SOURCE
        split = not args.no_binary
        if split:
            binary = os.path.abspath(args.binary) if args.binary else cargo_build()
            if not (os.path.isfile(binary) and os.access(binary, os.X_OK)):
                sys.exit(f"error: {binary} is not an executable file")
            source = os.path.join(tmp, "photongrid")
            stage(binary, source)
        m = manifest(source)
        suffix = f"-{PLATFORM.replace('-', '_')}" if split else ""
        out_path = os.path.join(out_dir, f"{m['id']}-{m['version']}{suffix}.zip")
        if os.path.exists(out_path):
            os.remove(out_path)
        tool = None if args.no_blender else bundled_extension_tool()
        if args.blender and not args.no_blender:
            build_with_blender(args.blender, source, out_dir, split)
        elif tool:
            build_with_tool(tool, source, out_dir, split)
        else:
            build_with_zipfile(source, out_path, PLATFORM if split else None)
    if not os.path.isfile(out_path):
        sys.exit(f"error: {out_path} was not written")
    with zipfile.ZipFile(out_path) as z:
        names = z.namelist()
    if "blender_manifest.toml" not in names or "__init__.py" not in names:
        sys.exit(f"error: {out_path} lacks blender_manifest.toml or __init__.py at its root: {names}")
    if split and ("bin/photongrid" not in names or "settings_schema.json" not in names):
        sys.exit(f"error: {out_path} lacks bin/photongrid or settings_schema.json: {names}")
    print(out_path)


if __name__ == "__main__":
    main()
