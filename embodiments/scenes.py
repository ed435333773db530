"""Named scenes a robot station builds in its world ("reality"), one function each."""

from __future__ import annotations

from collections.abc import Callable

from contactflow.embodiments.world import ScrewBottleSpec, World, box, cylinder


def thesis_7_3(world: World) -> None:
    """§7.3 (Fig. 7.4): a low box (a tissue box) stands in front of the target; push it aside, then pick the target."""
    world.add_table()
    world.add_object(box("obstacle_box", (0.08, 0.08, 0.06), xyz=(0.50, 0.0, 0.78), mass=0.2, friction=0.5))
    world.add_object(cylinder("target", 0.025, 0.12, xyz=(0.62, 0.0, 0.81), mass=0.15, friction=0.9))


def thesis_3_4_2(world: World) -> None:
    """§3.4.2 (Fig. 3.19): a bottle held upright in reach of the right hand (cap centre at 0.96 m), to be unscrewed."""
    world.add_table()
    world.add_screw_bottle(ScrewBottleSpec("bottle", xyz=(0.55, -0.3, 0.75)))


def table_only(world: World) -> None:
    world.add_table()


SCENES: dict[str, Callable[[World], None]] = {"thesis_7_3": thesis_7_3, "thesis_3_4_2": thesis_3_4_2, "table": table_only}
