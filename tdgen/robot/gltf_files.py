"""A glTF model's other files: the buffers and images a .gltf names by URI, and the model packed into one GLB.

A .gltf may keep its geometry and textures in files beside it (`buffers[].uri` such as `part.bin`,
`images[].uri`), while a scene names only the .gltf. Whoever reads the model on another host (a consumer of a
served scene, the tdgen service fetching a robot's file) needs all of it in one file: the GLB of the same JSON,
its buffers and images in the one binary chunk. Packed by hand after the glTF 2.0 specification's GLB layout
rather than exported again by trimesh, so nothing is decoded or encoded again: the same accessors over the same
bytes, textures included without an image library (pygltflib converts the same way, through its dataclasses
and three more dependencies, for what is a header and two chunks here). Packing is one copy of the bytes,
nothing decoded: done for each request, nothing kept between them.

A .gltf may name files in its own folder or below it only, once `..` and symbolic links are followed: a served
scene's model never carries a file from elsewhere on its host. `data:` URIs are read from the JSON itself.
"""
from __future__ import annotations

import base64
import json
import struct
from pathlib import Path
from typing import Any
from urllib.parse import unquote, unquote_to_bytes, urlsplit

from tdgen.robot.errors import SceneError

SUFFIX = ".gltf"
IMAGE_TYPES = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".webp": "image/webp",
               ".ktx2": "image/ktx2"}
_MAGIC, _VERSION, _JSON, _BIN = 0x46546C67, 2, 0x4E4F534A, 0x004E4942  # "glTF", 2, "JSON", "BIN\0"
_ALIGN = 8  # each buffer starts where any accessor's component (at most 4 bytes) stays aligned


def is_gltf(path: str | Path) -> bool:
    return Path(path).suffix.lower() == SUFFIX


def named_files(path: Path) -> list[tuple[str, Path]]:
    """(URI, path here) of each file the .gltf `path` names for its buffers and images, in the JSON's order;
    a SceneError for a URI that is not a file in its folder."""
    gltf = _json(path)
    return [(uri, _file(path, uri)) for uri in _uris(gltf) if not uri.startswith("data:")]


def check_whole(path: Path) -> None:
    """A SceneError naming the .gltf and the first file it names that is not there."""
    for uri, file in named_files(path):
        if not file.is_file():
            raise SceneError(f"{path}: names {uri!r}, which is not there ({file})")


def check_glb_alone(path: Path) -> None:
    """A SceneError naming the .glb `path` and the first file its JSON names: a GLB is served as it is, so it
    must hold its buffers and images itself (the specification lets it name files; a consumer on another host
    would get none of them)."""
    try:
        with path.open("rb") as f:  # the header and the JSON chunk only: the binary chunk may be large
            head = f.read(20)
            if len(head) < 20:
                return  # too short for a JSON chunk: the mesh reader says what is wrong with it
            magic, _, _, length, kind = struct.unpack("<IIIII", head)
            if magic != _MAGIC or kind != _JSON:
                return
            chunk = f.read(length)
    except OSError as e:
        raise SceneError(f"{path}: cannot read the file ({e.strerror})") from None
    try:
        gltf = json.loads(chunk.decode("utf-8"))
    except ValueError:
        return
    named = [uri for uri in _uris(gltf) if not uri.startswith("data:")] if isinstance(gltf, dict) else []
    if named:
        raise SceneError(f"{path}: names {named[0]!r} outside itself (a .glb must hold its buffers and images; "
                         "name the .gltf with its files beside it instead, or pack them into the .glb)")


def pack_glb(path: Path) -> bytes:
    """The .gltf `path` as one GLB: its JSON with every buffer and image in the binary chunk."""
    gltf = _json(path)
    try:
        return _packed(path, gltf)
    except (KeyError, IndexError, TypeError, ValueError) as e:  # a JSON that is not glTF where it counts
        raise SceneError(f"{path}: not a valid glTF ({type(e).__name__}: {e})") from None


def _packed(path: Path, gltf: dict[str, Any]) -> bytes:
    parts: list[bytes | memoryview] = []  # the binary chunk's pieces, joined once: a model's bytes copied once
    size = 0

    def append(data: bytes | memoryview, align: int) -> int:
        nonlocal size
        if size % align:
            parts.append(b"\0" * (-size % align))
            size += -size % align
        parts.append(data)
        size += len(data)
        return size - len(data)

    starts = []
    for k, buffer in enumerate(gltf.get("buffers") or []):
        if "uri" not in buffer:
            raise SceneError(f"{path}: buffer {k} has no uri (only a GLB's first buffer may have none)")
        data, length = _content(path, buffer["uri"])[0], int(buffer["byteLength"])
        if len(data) < length:
            raise SceneError(f"{path}: names {buffer['uri']!r} of {length} bytes, which holds {len(data)}")
        starts.append(append(memoryview(data)[:length], _ALIGN))
    views = gltf.get("bufferViews") or []
    for view in views:
        for holder in (view, (view.get("extensions") or {}).get("EXT_meshopt_compression")):
            if holder:  # meshopt's compressed view names a buffer of its own
                holder["byteOffset"] = starts[holder["buffer"]] + int(holder.get("byteOffset", 0))
                holder["buffer"] = 0
    for image in gltf.get("images") or []:
        if "uri" in image:
            data, media = _content(path, image.pop("uri"))
            views.append({"buffer": 0, "byteOffset": append(data, 4), "byteLength": len(data)})
            image["bufferView"] = len(views) - 1
            image.setdefault("mimeType", media)
    if views:
        gltf["bufferViews"] = views
    if size:
        gltf["buffers"] = [{"byteLength": size}]
    else:
        gltf.pop("buffers", None)
    text = json.dumps(gltf, separators=(",", ":"), ensure_ascii=False).encode()
    text += b" " * (-len(text) % 4)
    chunks: list[bytes | memoryview] = [struct.pack("<II", len(text), _JSON), text]
    if size:
        padding = b"\0" * (-size % 4)
        chunks += [struct.pack("<II", size + len(padding), _BIN), *parts, padding]
    length = 12 + sum(len(chunk) for chunk in chunks)
    return b"".join([struct.pack("<III", _MAGIC, _VERSION, length), *chunks])


def _json(path: Path) -> dict[str, Any]:
    try:
        gltf = json.loads(path.read_bytes().decode("utf-8-sig"))
    except OSError as e:
        raise SceneError(f"{path}: cannot read the file ({e.strerror})") from None
    except ValueError as e:
        raise SceneError(f"{path}: not a glTF's JSON ({str(e).splitlines()[0][:160]})") from None
    if not isinstance(gltf, dict):
        raise SceneError(f"{path}: not a glTF's JSON (an object is expected)")
    return gltf


def _uris(gltf: dict[str, Any]) -> list[str]:
    items = [*(gltf.get("buffers") or []), *(gltf.get("images") or [])]
    return [item["uri"] for item in items if isinstance(item, dict) and isinstance(item.get("uri"), str)]


def _file(path: Path, uri: str) -> Path:
    """The file a relative URI of the .gltf `path` names; a SceneError for any other URI."""
    if urlsplit(uri).scheme:
        raise SceneError(f"{path}: names {uri!r}, not a file beside it (a glTF's files are read by relative "
                         "URIs and data: URIs only)")
    folder = path.parent
    file = folder / unquote(uri)
    if not file.resolve().is_relative_to(folder.resolve()):
        raise SceneError(f"{path}: names {uri!r}, outside its folder (a glTF's files must be in its folder or "
                         "below it, once '..' and links are followed)")
    return file


def _content(path: Path, uri: str) -> tuple[bytes, str]:
    """The bytes a URI of the .gltf names, and their media type."""
    if uri.startswith("data:"):
        head, _, data = uri[5:].partition(",")
        media = head.split(";")[0] or "application/octet-stream"
        try:
            return (base64.b64decode(data, validate=True) if head.endswith(";base64") else unquote_to_bytes(data)), media
        except ValueError:
            raise SceneError(f"{path}: a data: URI that is not base64 ({uri[:40]}...)") from None
    file = _file(path, uri)
    try:
        return file.read_bytes(), IMAGE_TYPES.get(file.suffix.lower(), "application/octet-stream")
    except FileNotFoundError:
        raise SceneError(f"{path}: names {uri!r}, which is not there ({file})") from None
    except OSError as e:
        raise SceneError(f"{path}: names {uri!r}, which cannot be read ({file}: {e.strerror})") from None
