#!/usr/bin/env python3
"""Subdivide every triangle of a GLB into 4 (edge midpoints), LEVELS times: the same scene
(flat faces stay flat, curved ones keep their facets) with 4^LEVELS times the triangles, for
the cost-against-size table (bench/scaling.sh, docs/performance.md).

    python3 bench/subdivide_glb.py IN.glb OUT.glb LEVELS

Handles indexed and non-indexed TRIANGLES primitives with POSITION, NORMAL, TEXCOORD_n and
TANGENT (interpolated; normals renormalised); other attributes are dropped. Buffer views of
images are copied. Needs numpy.
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tools"))
from glb import accessor, read_glb, write_glb  # noqa: E402

KEPT = ("POSITION", "NORMAL", "TANGENT")


def subdivide(tris, attrs):
    """One level: each triangle (index triple) becomes four; new vertices at edge midpoints."""
    n = len(next(iter(attrs.values())))
    edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    edges.sort(axis=1)
    unique, inverse = np.unique(edges, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    mid = n + inverse.reshape(3, -1).T  # midpoint vertex of edges 01, 12, 20 per triangle
    out = {}
    for name, v in attrs.items():
        m = 0.5 * (v[unique[:, 0]] + v[unique[:, 1]])
        if name == "NORMAL":
            m /= np.maximum(np.linalg.norm(m, axis=1, keepdims=True), 1e-12)
        if name == "TANGENT":
            m[:, :3] /= np.maximum(np.linalg.norm(m[:, :3], axis=1, keepdims=True), 1e-12)
            m[:, 3] = v[unique[:, 0], 3]
        out[name] = np.concatenate([v, m.astype(v.dtype)])
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    ab, bc, ca = mid[:, 0], mid[:, 1], mid[:, 2]
    new = np.concatenate(
        [np.stack(t, axis=1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))]
    )
    return new, out


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    src, dst, levels = sys.argv[1], sys.argv[2], int(sys.argv[3])
    doc, binary = read_glb(src)
    out = bytearray()
    views, accessors = [], []

    def add_view(data, target=None):
        while len(out) % 4:
            out.append(0)
        view = {"buffer": 0, "byteOffset": len(out), "byteLength": len(data)}
        if target:
            view["target"] = target
        out.extend(data)
        views.append(view)
        return len(views) - 1

    def add_accessor(array, component, kind, target):
        acc = {
            "bufferView": add_view(array.tobytes(), target),
            "componentType": component,
            "count": len(array),
            "type": kind,
        }
        if kind == "VEC3" and component == 5126:
            acc["min"] = array.min(axis=0).tolist()
            acc["max"] = array.max(axis=0).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    for image in doc.get("images", []):
        if "bufferView" in image:
            v = doc["bufferViews"][image["bufferView"]]
            start = v.get("byteOffset", 0)
            image["bufferView"] = add_view(binary[start : start + v["byteLength"]])
    triangles = 0
    for mesh in doc.get("meshes", []):
        for prim in mesh["primitives"]:
            if prim.get("mode", 4) != 4:
                sys.exit(f"{src}: mesh '{mesh.get('name')}' has a primitive that is not TRIANGLES")
            attrs = {k: accessor(doc, binary, i).astype(np.float32) for k, i in prim["attributes"].items()
                     if k in KEPT or k.startswith("TEXCOORD_")}
            n = len(attrs["POSITION"])
            tris = (accessor(doc, binary, prim["indices"]).reshape(-1, 3).astype(np.int64)
                    if "indices" in prim else np.arange(n).reshape(-1, 3))
            for _ in range(levels):
                tris, attrs = subdivide(tris, attrs)
            triangles += len(tris)
            prim["attributes"] = {
                k: add_accessor(v, 5126, {2: "VEC2", 3: "VEC3", 4: "VEC4"}[v.shape[1]], 34962)
                for k, v in attrs.items()
            }
            prim["indices"] = add_accessor(tris.astype(np.uint32).reshape(-1), 5125, "SCALAR", 34963)
            prim.pop("targets", None)
    doc["accessors"], doc["bufferViews"] = accessors, views
    doc["buffers"] = [{"byteLength": len(out)}]
    write_glb(dst, doc, out)
    print(f"{dst}: {triangles} triangles")


if __name__ == "__main__":
    main()
