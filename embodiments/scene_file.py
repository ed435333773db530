"""Scene files (YAML): one cell of a world, its robots with their base poses, the table and the objects.

Example::

    scene: table                 # a named scene of embodiments.scenes (default: an empty floor)
    robots:
      - {name: tombatossals}                         # at the embodiment's own placement
      - {name: melfa_2, embodiment: melfa, base: [1.3, 0.0, 0.0, 0.0, 0.0, 3.14159]}
    objects:
      - {name: cyl, kind: cylinder, radius: 0.03, length: 0.12, xyz: [0.55, -0.3, 0.81], mass: 0.2, friction: 0.8}
      - {name: cube, kind: box, size: [0.05, 0.05, 0.05], xyz: [0.5, 0.1, 0.775]}
      - {name: ball, kind: sphere, radius: 0.03, xyz: [0.6, 0.2, 0.78]}
      - name: spray                                  # several shapes, each placed in the object frame
        xyz: [0.4, 0.0, 0.751]
        shapes:
          - {kind: cylinder, radius: 0.025, length: 0.16, xyz: [0.0, 0.0, 0.08]}
          - {kind: box, size: [0.03, 0.02, 0.03], xyz: [0.01, 0.0, 0.175]}
      - {name: bottle, kind: screw_bottle, xyz: [0.5, 0.0, 0.75], thread_turns: 0.5}  # stands free; static: welded
    cameras:                     # fixed depth cameras of the cell (a head-like camera no robot carries)
      - {name: head, eye: [-0.1, 0.1, 1.45], target: [0.56, 0.1, 0.82]}

A ``screw_bottle`` (thesis §3.3.6) takes the fields of ``ScrewBottleSpec`` (``body_radius``, ``thread_turns``, ...;
``xyz`` is the centre of its bottom face); it stands free unless ``static``.

A camera looks from ``eye`` at ``target`` (m, world), the image's up toward +z; it takes ``width`` and ``height``
(px, default 640 x 480, the Kinect's intrinsics scaled) and streams on ``camera/<name>/depth``.

Poses are ``[x, y, z, roll, pitch, yaw]`` (m, rad, world). Errors name the file, line and field.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from contactflow.nodes.yamldoc import YamlDoc

_TOP = {"scene", "robots", "objects", "cameras"}
_CAMERA = {"name", "eye", "target", "width", "height"}
_ROBOT = {"name", "embodiment", "base"}
_OBJECT = {"name", "kind", "size", "radius", "length", "shapes", "xyz", "rpy", "mass", "friction", "static"}
_SHAPE = {"kind", "size", "radius", "length", "xyz", "rpy"}
_BOTTLE = ("body_radius", "body_height", "neck_radius", "neck_height", "cap_radius", "cap_height", "cap_mass",
           "thread_friction", "thread_damping", "thread_turns", "friction", "density")
"""A screw bottle's numeric fields (ScrewBottleSpec's), besides name, kind, xyz and static."""
_SHAPE_FIELDS = {"box": ("size",), "cylinder": ("radius", "length"), "sphere": ("radius",)}


@dataclass(frozen=True)
class RobotPlacement:
    name: str  # the robot's name on the key space (unique in the site)
    embodiment: str  # registry name
    base: tuple[float, ...] | None  # [x, y, z, roll, pitch, yaw] (m, rad); None: the embodiment's placement


@dataclass(frozen=True)
class CameraPlacement:
    name: str  # the camera's name on the key space (camera/<name>/depth)
    eye: tuple[float, float, float]  # m, world: where it is
    target: tuple[float, float, float]  # m, world: what it looks at
    width: int = 640  # px
    height: int = 480  # px


@dataclass(frozen=True)
class SceneFile:
    scene: str
    robots: tuple[RobotPlacement, ...]
    objects: tuple  # ObjectSpec
    file: str = "<scene>"
    bottles: tuple = ()  # ScrewBottleSpec
    cameras: tuple[CameraPlacement, ...] = ()


def _floats(doc: YamlDoc, path: tuple, n: int) -> tuple[float, ...]:
    values = doc.get(path, list)
    if len(values) != n or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
        raise doc.error(path, f"expected {n} numbers, got {values!r}")
    return tuple(float(v) for v in values)


def _number(doc: YamlDoc, path: tuple, default: float | object = ...) -> float:
    v = doc.get(path, (int, float), default)
    if isinstance(v, bool) or not float(v) > 0:
        raise doc.error(path, f"expected a positive number, got {v!r}")
    return float(v)


def parse_scene(doc: YamlDoc) -> SceneFile:
    """Validate a scene document; nothing is built (no SAPIEN here)."""
    from contactflow.embodiments import registry
    from contactflow.embodiments.scenes import SCENES
    from contactflow.embodiments.world import ObjectSpec

    doc.mapping((), _TOP)
    scene = doc.get(("scene",), str, "")
    if scene and scene not in SCENES:
        raise doc.error(("scene",), f"{scene!r} is not one of {sorted(SCENES)}")
    robots: list[RobotPlacement] = []
    for i, _ in enumerate(doc.get(("robots",), list)):
        p = ("robots", i)
        doc.mapping(p, _ROBOT)
        name = doc.get(p + ("name",), str)
        emb = doc.get(p + ("embodiment",), str, name)
        if emb not in registry.names():
            raise doc.error(p + ("embodiment",), f"{emb!r} is not a robot of the registry ({registry.names()})")
        if any(r.name == name for r in robots):
            raise doc.error(p + ("name",), f"robot {name!r} is placed twice")
        base = _floats(doc, p + ("base",), 6) if doc.get(p + ("base",), list, None) is not None else None
        robots.append(RobotPlacement(name, emb, base))
    if not robots:
        raise doc.error(("robots",), "a scene needs at least one robot")
    objects, bottles = [], []
    for i, _ in enumerate(doc.get(("objects",), list, [])):
        p = ("objects", i)
        if doc.get(p + ("kind",), str, "") == "screw_bottle":
            bottle = _bottle(doc, p)
            if any(o.name == bottle.name for o in objects + bottles):
                raise doc.error(p + ("name",), f"object {bottle.name!r} is defined twice")
            bottles.append(bottle)
            continue
        fields = doc.mapping(p, _OBJECT)
        name = doc.get(p + ("name",), str)
        if "shapes" in fields:
            for f in sorted({"kind", "size", "radius", "length"} & set(fields)):
                raise doc.error(p + (f,), f"an object with shapes gives {f!r} per shape")
            shapes = tuple(_shape(doc, p + ("shapes", k), placed=True)
                           for k, _ in enumerate(doc.get(p + ("shapes",), list)))
            if not shapes:
                raise doc.error(p + ("shapes",), "an object needs at least one shape")
            kind = "object"
        else:
            shapes = (_shape(doc, p, placed=False),)
            kind = shapes[0].kind
        xyz = _floats(doc, p + ("xyz",), 3)
        rpy = _floats(doc, p + ("rpy",), 3) if doc.get(p + ("rpy",), list, None) is not None else (0.0, 0.0, 0.0)
        mass = _number(doc, p + ("mass",), 0.2)
        friction = _number(doc, p + ("friction",), 0.6)
        static = doc.get(p + ("static",), bool, False)
        if any(o.name == name for o in objects + bottles):
            raise doc.error(p + ("name",), f"object {name!r} is defined twice")
        objects.append(ObjectSpec(name, shapes, mass, friction, xyz, rpy, static, kind))
    return SceneFile(scene, tuple(robots), tuple(objects), doc.file, tuple(bottles), _cameras(doc))


def _cameras(doc: YamlDoc) -> tuple[CameraPlacement, ...]:
    """The fixed cameras of a scene document."""
    from contactflow.nodes.keys import ANY, KeyExprError, segment

    out: list[CameraPlacement] = []
    for i, _ in enumerate(doc.get(("cameras",), list, [])):
        p = ("cameras", i)
        doc.mapping(p, _CAMERA)
        name = doc.get(p + ("name",), str)
        try:
            if name == ANY:
                raise KeyExprError("a camera needs a name, not the wildcard '*'")
            segment(name, "camera")
        except KeyExprError as exc:
            raise doc.error(p + ("name",), str(exc)) from None
        if any(c.name == name for c in out):
            raise doc.error(p + ("name",), f"camera {name!r} is placed twice")
        eye, target = _floats(doc, p + ("eye",), 3), _floats(doc, p + ("target",), 3)
        if sum((a - b) ** 2 for a, b in zip(eye, target, strict=True)) < 1e-6:
            raise doc.error(p + ("target",), f"the camera looks at its own eye {list(eye)}")
        size = []
        for f, default in (("width", 640), ("height", 480)):
            v = doc.get(p + (f,), int, default)
            if isinstance(v, bool) or not 8 <= v <= 4096:
                raise doc.error(p + (f,), f"expected a whole number of pixels in 8..4096, got {v!r}")
            size.append(v)
        out.append(CameraPlacement(name, eye, target, *size))  # type: ignore[arg-type]
    return tuple(out)


def _bottle(doc: YamlDoc, p: tuple):
    """The screw bottle at ``p``: ScrewBottleSpec's defaults for what the entry leaves out."""
    from contactflow.embodiments.world import ScrewBottleSpec

    fields = doc.mapping(p, {"name", "kind", "xyz", "static", *_BOTTLE})
    values = {}
    for f in sorted(set(_BOTTLE) & set(fields)):
        v = doc.get(p + (f,), (int, float))
        thread = f.startswith("thread")  # a thread may be frictionless, undamped or already loose: 0 is allowed
        if isinstance(v, bool) or not (float(v) >= 0 if thread else float(v) > 0):
            raise doc.error(p + (f,), f"expected a {'non-negative' if thread else 'positive'} number, got {v!r}")
        values[f] = float(v)
    return ScrewBottleSpec(doc.get(p + ("name",), str), _floats(doc, p + ("xyz",), 3),
                           fixed=doc.get(p + ("static",), bool, False), **values)


def _shape(doc: YamlDoc, p: tuple, placed: bool):
    """One shape at ``p``: its kind and extents; ``placed`` shapes also take a pose in the object frame."""
    from contactflow.embodiments.world import ShapeSpec

    fields = doc.mapping(p, _SHAPE) if placed else set(doc.get(p, dict))
    kind = doc.get(p + ("kind",), str)
    if kind not in _SHAPE_FIELDS:
        raise doc.error(p + ("kind",), f"{kind!r} is not one of {sorted(_SHAPE_FIELDS)}")
    for f in sorted({"size", "radius", "length"} - set(_SHAPE_FIELDS[kind]) & set(fields)):
        raise doc.error(p + (f,), f"a {kind} has no {f!r} (it takes {list(_SHAPE_FIELDS[kind])})")
    if kind == "box":
        size = _floats(doc, p + ("size",), 3)
        if min(size) <= 0:
            raise doc.error(p + ("size",), f"sizes must be positive, got {list(size)}")
    elif kind == "cylinder":
        size = (_number(doc, p + ("radius",)), _number(doc, p + ("length",)))
    else:
        size = (_number(doc, p + ("radius",)),)
    if not placed:
        return ShapeSpec(kind, size)
    at = _floats(doc, p + ("xyz",), 3) if "xyz" in fields else (0.0, 0.0, 0.0)
    rpy = _floats(doc, p + ("rpy",), 3) if "rpy" in fields else (0.0, 0.0, 0.0)
    return ShapeSpec(kind, size, at, rpy)


def object_entry(spec) -> dict:
    """A scene file's entry for ``spec`` (an ObjectSpec), the inverse of what :func:`parse_scene` reads."""
    def floats(v) -> list[float]:
        return [float(c) for c in v]

    def extents(s) -> dict:
        if s.kind == "box":
            return {"kind": "box", "size": floats(s.size)}
        if s.kind == "cylinder":
            return {"kind": "cylinder", "radius": float(s.size[0]), "length": float(s.size[1])}
        if s.kind == "sphere":
            return {"kind": "sphere", "radius": float(s.size[0])}
        raise ValueError(f"object {spec.name!r}: a scene file has no {s.kind!r} shapes")

    out: dict = {"name": spec.name}
    if len(spec.shapes) == 1 and spec.shapes[0].xyz == (0.0, 0.0, 0.0) and spec.shapes[0].rpy == (0.0, 0.0, 0.0):
        out.update(extents(spec.shapes[0]))
    else:
        out["shapes"] = [{**extents(s), "xyz": floats(s.xyz), "rpy": floats(s.rpy)} for s in spec.shapes]
    out.update(xyz=floats(spec.xyz), rpy=floats(spec.rpy), mass=float(spec.mass), friction=float(spec.friction))
    if spec.static:
        out["static"] = True
    return out


def bottle_entry(spec) -> dict:
    """A scene file's entry for ``spec`` (a ScrewBottleSpec), the inverse of what :func:`parse_scene` reads."""
    out: dict = {"name": spec.name, "kind": "screw_bottle", "xyz": [float(c) for c in spec.xyz]}
    out.update({f: float(getattr(spec, f)) for f in _BOTTLE})
    if spec.fixed:
        out["static"] = True
    return out


def load_scene(path: str | Path) -> SceneFile:
    """A scene file by path, or a cell shipped in ``embodiments/cells`` by name (``pick_place``)."""
    shipped = Path(__file__).parent / "cells" / f"{path}.yaml"
    if not Path(path).exists() and "/" not in str(path) and shipped.exists():
        path = shipped
    return parse_scene(YamlDoc.load(path))
