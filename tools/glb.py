"""Read and write binary glTF (.glb) files: the JSON document and its binary chunk, and an
accessor's elements as a numpy array. Shared by the Python tools and benchmarks that edit or
convert the sample and reference scenes. Needs numpy."""

import json
import struct
import sys

import numpy as np

COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
GLTF, JSON, BIN = 0x46546C67, 0x4E4F534A, 0x004E4942


def read_glb(path):
    """The document and the binary chunk of the .glb at `path`."""
    data = open(path, "rb").read()
    if len(data) < 12 or struct.unpack_from("<I", data, 0)[0] != GLTF:
        sys.exit(f"{path}: not a GLB file")
    offset, doc, binary = 12, None, b""
    while offset + 8 <= len(data):
        length, kind = struct.unpack_from("<II", data, offset)
        chunk = data[offset + 8 : offset + 8 + length]
        if kind == JSON:
            doc = json.loads(chunk)
        elif kind == BIN:
            binary = chunk
        offset += 8 + length
    if doc is None:
        sys.exit(f"{path}: no JSON chunk")
    return doc, binary


def write_glb(path, doc, binary):
    """Write `doc` and `binary` as a .glb (chunks padded to 4 bytes)."""
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    binary = bytes(binary) + b"\0" * (-len(binary) % 4)
    with open(path, "wb") as f:
        f.write(struct.pack("<III", GLTF, 2, 12 + 8 + len(text) + 8 + len(binary)))
        f.write(struct.pack("<II", len(text), JSON) + text)
        f.write(struct.pack("<II", len(binary), BIN) + binary)


def accessor(doc, binary, index):
    """Accessor `index`'s elements, one row each (strided views read too)."""
    a = doc["accessors"][index]
    view = doc["bufferViews"][a["bufferView"]]
    dtype = np.dtype(COMPONENT[a["componentType"]])
    width = WIDTH[a["type"]]
    start = view.get("byteOffset", 0) + a.get("byteOffset", 0)
    stride = view.get("byteStride", 0) or dtype.itemsize * width
    count = a["count"]
    raw = np.frombuffer(binary, dtype=np.uint8, count=stride * (count - 1) + dtype.itemsize * width, offset=start)
    rows = np.lib.stride_tricks.as_strided(raw, shape=(count, dtype.itemsize * width), strides=(stride, 1))
    return np.ascontiguousarray(rows).view(dtype).reshape(count, width)
