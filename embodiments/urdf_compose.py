"""Compose robot URDFs from example-robot-data parts by XML merging, written to a cache dir.

The composition is data: a :class:`Part` names a source URDF, a name prefix, the links to
drop (e.g. the panda hand when an allegro hand replaces it) and the fixed joint that mounts
it on a link of the assembly. ``package://`` mesh paths are rewritten to absolute paths,
because SAPIEN does not resolve them for URDFs we write ourselves.
"""

from __future__ import annotations

import hashlib
import os
import pathlib
import sysconfig
from dataclasses import dataclass, field
from xml.etree import ElementTree as ET

import defusedxml.ElementTree as DET

_ERD_PACKAGE = "package://example-robot-data/robots/"
_FORMAT = 2
"""Bumped when the written URDF changes for the same composition (invalidates the cache)."""


class UrdfError(ValueError):
    """A part or a composition is inconsistent (names the file and element)."""


def erd_robots_dir() -> pathlib.Path:
    """The ``robots`` folder of the installed example-robot-data (cmeel prefix)."""
    candidates = [pathlib.Path(sysconfig.get_paths()[k]) / "cmeel.prefix/share/example-robot-data/robots"
                  for k in ("purelib", "platlib")]
    for c in candidates:
        if c.is_dir():
            return c
    raise UrdfError(f"example-robot-data robots folder not found (looked in {[str(c) for c in candidates]})")


def erd_file(rel: str) -> pathlib.Path:
    """Absolute path of ``rel`` inside example-robot-data's robots folder."""
    p = erd_robots_dir() / rel
    if not p.is_file():
        raise UrdfError(f"example-robot-data file {rel!r} does not exist ({p})")
    return p


def cache_dir(kind: str = "urdf") -> pathlib.Path:
    """Where composed URDFs (``kind`` urdf) and other derived robot files are written (``$CONTACTFLOW_CACHE`` or
    ``~/.cache/contactflow``, a folder per kind)."""
    root = os.environ.get("CONTACTFLOW_CACHE") or str(pathlib.Path.home() / ".cache" / "contactflow")
    d = pathlib.Path(root) / kind
    d.mkdir(parents=True, exist_ok=True)
    return d


@dataclass(frozen=True)
class Mount:
    """A fixed joint placing a part's root link on ``parent`` (a link already in the assembly)."""

    parent: str
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Part:
    """One URDF file merged into an assembly."""

    source: str  # path relative to example-robot-data/robots
    prefix: str = ""  # prepended to every link and joint name of the part
    drop_links: tuple[str, ...] = ()  # links removed with every joint touching them (unprefixed)
    mount: Mount | None = None  # None: the part's root becomes (or joins) the assembly root
    drop_root: str = ""  # a root link to remove (e.g. a "world" link); its child becomes root


@dataclass(frozen=True)
class ExtraLink:
    """A link added by the composition (torso, head, camera), with optional box collision."""

    name: str
    parent: str
    joint: str
    joint_type: str = "fixed"  # fixed | revolute
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    limits: tuple[float, float] = (-1.57, 1.57)
    box: tuple[float, float, float] | None = None  # m, collision box size (also its visual in a rendering URDF)
    box_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mass: float = 0.5  # kg


@dataclass(frozen=True)
class Composition:
    """A robot assembled from parts, extra links and a root link."""

    name: str
    root: str = ""  # name of an extra root link created first ("" = first part's root)
    parts: tuple[Part, ...] = ()
    extras: tuple[ExtraLink, ...] = field(default_factory=tuple)

    def digest(self) -> str:
        # the URDF holds absolute mesh paths into one installation's example-robot-data: another checkout's (a
        # removed CI clone's venv) sharing the cache wrote paths that no longer exist, and no robot loaded
        return hashlib.sha1(f"{_FORMAT}:{erd_robots_dir()}:{self!r}".encode()).hexdigest()[:10]


def _fmt(v: tuple[float, ...]) -> str:
    return " ".join(f"{x:.9g}" for x in v)


def _load(rel: str) -> ET.Element:
    path = erd_file(rel)
    text = path.read_text()
    text = text.replace(_ERD_PACKAGE, str(erd_robots_dir()) + "/")
    root = DET.fromstring(text)
    if root.tag != "robot":
        raise UrdfError(f"{path}: root element is <{root.tag}>, expected <robot>")
    return root


def _inertial(mass: float) -> ET.Element:
    i = ET.Element("inertial")
    ET.SubElement(i, "origin", xyz="0 0 0", rpy="0 0 0")
    ET.SubElement(i, "mass", value=f"{mass:.6g}")
    d = 1e-3 * max(mass, 1e-3)
    ET.SubElement(i, "inertia", ixx=f"{d}", ixy="0", ixz="0", iyy=f"{d}", iyz="0", izz=f"{d}")
    return i


def _extra_link(e: ExtraLink, visuals: bool = False) -> list[ET.Element]:
    link = ET.Element("link", name=e.name)
    link.append(_inertial(e.mass))
    if e.box is not None:
        for tag in ("collision", "visual") if visuals else ("collision",):
            g = ET.SubElement(link, tag)
            ET.SubElement(g, "origin", xyz=_fmt(e.box_xyz), rpy="0 0 0")
            geom = ET.SubElement(g, "geometry")
            ET.SubElement(geom, "box", size=_fmt(e.box))
    out = [link]
    if e.parent:
        j = ET.Element("joint", name=e.joint, type=e.joint_type)
        ET.SubElement(j, "parent", link=e.parent)
        ET.SubElement(j, "child", link=e.name)
        ET.SubElement(j, "origin", xyz=_fmt(e.xyz), rpy=_fmt(e.rpy))
        if e.joint_type != "fixed":
            ET.SubElement(j, "axis", xyz=_fmt(e.axis))
            ET.SubElement(j, "limit", lower=f"{e.limits[0]}", upper=f"{e.limits[1]}", effort="20", velocity="2")
            ET.SubElement(j, "dynamics", damping="0.0", friction="0.0")
        out.append(j)
    return out


def _part_elements(part: Part, visuals: bool = False) -> tuple[list[ET.Element], str]:
    """Links and joints of a part after dropping and prefixing; returns them and the root link."""
    src = _load(part.source)
    drop = set(part.drop_links)
    if part.drop_root:
        drop.add(part.drop_root)
    links = [el for el in src if el.tag == "link"]
    joints = [el for el in src if el.tag == "joint"]
    names = {el.get("name") for el in links}
    for d in drop:
        if d not in names:
            raise UrdfError(f"{part.source}: drop_links names {d!r}, which is not a link of the file")
    links = [el for el in links if el.get("name") not in drop]
    if not visuals:
        # the physics-only loader needs a render device to parse visuals
        for el in links:
            for v in el.findall("visual"):
                el.remove(v)
    kept_joints = []
    for j in joints:
        parent, child = j.find("parent").get("link"), j.find("child").get("link")
        if parent in drop or child in drop:
            continue
        kept_joints.append(j)
    kept_names = {j.get("name") for j in kept_joints}
    children = {j.find("child").get("link") for j in kept_joints}
    roots = [el.get("name") for el in links if el.get("name") not in children]
    if len(roots) != 1:
        raise UrdfError(f"{part.source}: after dropping {sorted(drop)} the part has roots {roots}, expected one")
    p = part.prefix
    for el in links:
        el.set("name", p + el.get("name"))
    for j in kept_joints:
        j.set("name", p + j.get("name"))
        for tag in ("parent", "child"):
            j.find(tag).set("link", p + j.find(tag).get("link"))
        m = j.find("mimic")
        if m is not None:
            if m.get("joint") not in kept_names:
                j.remove(m)
            else:
                m.set("joint", p + m.get("joint"))
    return links + kept_joints, p + roots[0]


def compose(comp: Composition, visuals: bool = False) -> ET.Element:
    """The assembled ``<robot>`` element; ``visuals`` keeps the parts' visual elements (rendering scenes)."""
    robot = ET.Element("robot", name=comp.name)
    existing: set[str] = set()

    def add(elements: list[ET.Element], where: str) -> None:
        for el in elements:
            key = f"{el.tag}:{el.get('name')}"
            if key in existing:
                raise UrdfError(f"composition {comp.name}: {where} adds duplicate {el.tag} {el.get('name')!r}")
            existing.add(key)
            robot.append(el)

    extras_by_parent: dict[str, list[ExtraLink]] = {}
    for e in comp.extras:
        extras_by_parent.setdefault(e.parent, []).append(e)
    if comp.root:
        add(_extra_link(ExtraLink(name=comp.root, parent="", joint="", mass=10.0)), "root")
    pending = list(comp.extras)
    placed = {comp.root} if comp.root else set()

    def place_extras() -> None:
        progress = True
        while progress:
            progress = False
            for e in list(pending):
                if e.parent in placed:
                    add(_extra_link(e, visuals), f"extra link {e.name}")
                    placed.add(e.name)
                    pending.remove(e)
                    progress = True

    place_extras()
    for part in comp.parts:
        elements, root = _part_elements(part, visuals)
        if part.mount is not None:
            if f"link:{part.mount.parent}" not in existing:
                raise UrdfError(f"composition {comp.name}: part {part.source} mounts on unknown link {part.mount.parent!r}")
            j = ET.Element("joint", name=f"{root}_mount", type="fixed")
            ET.SubElement(j, "parent", link=part.mount.parent)
            ET.SubElement(j, "child", link=root)
            ET.SubElement(j, "origin", xyz=_fmt(part.mount.xyz), rpy=_fmt(part.mount.rpy))
            elements.append(j)
        add(elements, f"part {part.source}")
        placed.update(el.get("name") for el in elements if el.tag == "link")
        place_extras()
    if pending:
        raise UrdfError(f"composition {comp.name}: extra links {[e.name for e in pending]} have unknown parents")
    return robot


def write(comp: Composition, directory: pathlib.Path | None = None, visuals: bool = False) -> pathlib.Path:
    """Compose and write ``<name>-<digest>.urdf`` (``-visual.urdf`` with visuals) to the cache (reused when present)."""
    d = directory or cache_dir()
    path = d / f"{comp.name}-{comp.digest()}{'-visual' if visuals else ''}.urdf"
    if not path.exists():
        tree = ET.ElementTree(compose(comp, visuals))
        ET.indent(tree)
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tree.write(tmp, encoding="unicode", xml_declaration=True)
        tmp.replace(path)
    return path
