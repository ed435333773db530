"""Registry and URDF composition: every embodiment is data, composed URDFs load in pinocchio."""

from __future__ import annotations

import pinocchio as pin
import pytest

from contactflow.embodiments import registry
from contactflow.embodiments.urdf_compose import Composition, Mount, Part, UrdfError, compose


@pytest.mark.parametrize("name", ["tombatossals", "melfa", "baxter"])
def test_every_robot_is_registered_and_consistent(name, tmp_path):
    spec = registry.get(name)
    path = spec.urdf(tmp_path)
    model = pin.buildModelFromUrdf(str(path))
    joints = set(model.names)
    for arm in spec.arms:
        assert set(arm.joints) <= joints
        assert model.existFrame(arm.ee_frame)
    for hand in spec.hands:
        assert set(hand.joints) <= joints
        for pad in hand.pads:
            assert model.existFrame(pad.link)
    assert spec.capabilities is not None and "release" in spec.capabilities.primitives


def test_each_robot_has_one_home_found_by_its_package_and_typed_overrides():
    from contactflow.abstraction.factory import Factory
    from contactflow.nodes.params import replace_params
    from contactflow.nodes.registry import resolve

    assert registry.names() == ["baxter", "melfa", "tombatossals"]  # the packages under embodiments/robots/
    for name in registry.names():
        home = registry.home(name)
        assert home.name == name and home.spec is registry.get(name)
        assert issubclass(home.factory, Factory)
        for type_, changes in home.overrides.items():
            assert type_ in home.spec.capabilities.primitives, (name, type_)
            replace_params(resolve(type_).Params(), dict(changes), where=f"{name}.{type_}.")  # fields and types
    tomb = registry.home("tombatossals")
    assert tomb.overrides["detect_objects"]["wall_side"] == tomb.overrides["place_location"]["wall_side"] == tomb.wall_side
    assert registry.home("melfa").grasp_center == (0.0, 0.0, 0.0)


def test_a_grasp_centre_is_told_per_preshape_and_names_only_preshapes_the_hands_have():
    from dataclasses import replace

    tomb = registry.home("tombatossals")
    assert tomb.center("") == tomb.center("open") == tomb.center("cylindrical") == tomb.grasp_center
    assert tomb.center("claw") != tomb.grasp_center and "claw" in tomb.spec.hand("right_hand").preshapes
    with pytest.raises(registry.RegistryError, match=r"tombatossals.preshape_centers: \['fist'\] are no preshape"):
        replace(tomb, preshape_centers={"fist": (0.0, 0.0, 0.0)}).validate()


def test_tombatossals_composition_has_two_arms_hands_and_head(tmp_path):
    spec = registry.get("tombatossals")
    model = pin.buildModelFromUrdf(str(spec.urdf(tmp_path)))
    assert model.nq == 2 * 7 + 2 * 16 + 2
    assert [len(h.pads) for h in spec.hands] == [4, 4]
    assert all((p.rows, p.cols) == (5, 8) for h in spec.hands for p in h.pads)
    cam = spec.camera("kinect")
    assert (cam.width, cam.height) == (640, 480)
    assert {f.name for f in spec.fts} == {"left_ft", "right_ft"}


def test_melfa_is_six_dof_with_parallel_tactile_gripper():
    spec = registry.get("melfa")
    assert len(spec.arm("arm").joints) == 6
    hand = spec.hand("gripper")
    assert hand.kind == "parallel" and len(hand.pads) == 2


def test_baxter_ft_is_estimated():
    spec = registry.get("baxter")
    assert all(f.estimated for f in spec.fts)
    assert [len(a.joints) for a in spec.arms] == [7, 7]


def test_unknown_robot_and_names_raise_clearly():
    with pytest.raises(registry.RegistryError, match="unknown robot 'r2d2'"):
        registry.get("r2d2")
    with pytest.raises(registry.RegistryError, match="no arm 'middle'"):
        registry.get("melfa").arm("middle")


def test_grasp_corrections_are_capabilities_and_finger_lost_needs_fingers():
    from dataclasses import replace

    assert "finger_lost" in registry.get("tombatossals").capabilities.grasp_corrections
    # on wherever the hand allows it: tombatossals' home does not turn it off for its task files
    assert registry.home("tombatossals").overrides["robust_grasp"].get("finger_lost", True)
    for name in ("melfa", "baxter"):  # parallel grippers
        spec = registry.get(name)
        assert spec.capabilities.grasp_corrections == ("alignment", "sliding", "force_adaptation"), name
        claims = replace(spec, capabilities=replace(spec.capabilities, grasp_corrections=registry.GRASP_CORRECTIONS))
        with pytest.raises(registry.RegistryError, match=f"{name}.capabilities.grasp_corrections: finger_lost needs"):
            claims.validate()
    typo = replace(registry.get("tombatossals").capabilities, grasp_corrections=("alignement",))
    with pytest.raises(registry.RegistryError, match=r"unknown \['alignement'\]"):
        replace(registry.get("tombatossals"), capabilities=typo).validate()


def test_composition_errors_name_the_part():
    bad = Composition("x", parts=(Part("panda_description/urdf/panda.urdf", drop_links=("no_such_link",)),))
    with pytest.raises(UrdfError, match="panda.urdf: drop_links names 'no_such_link'"):
        compose(bad)
    orphan = Composition("y", parts=(Part("panda_description/urdf/panda.urdf", mount=Mount("ghost")),))
    with pytest.raises(UrdfError, match="unknown link 'ghost'"):
        compose(orphan)


def test_a_composed_urdf_of_another_installation_is_not_reused(tmp_path, monkeypatch):
    """The cache is shared by every checkout, and a composed URDF names meshes by absolute path: one written by
    another installation (a CI clone's venv, since removed) must not be read as this one's."""
    from contactflow.embodiments import urdf_compose

    spec = registry.get("melfa")
    mine = spec.urdf(tmp_path)
    erd = urdf_compose.erd_robots_dir()
    other = tmp_path / "other" / "robots"
    other.parent.mkdir()
    other.symlink_to(erd)
    monkeypatch.setattr(urdf_compose, "erd_robots_dir", lambda: other)
    theirs = spec.urdf(tmp_path)
    assert theirs != mine and str(other) in theirs.read_text() and str(other) not in mine.read_text()
    monkeypatch.undo()
    assert spec.urdf(tmp_path) == mine
