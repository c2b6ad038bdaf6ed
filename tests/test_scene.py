"""Scene-file validation: every mistake names its key; geometry and calibration are right."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from galileo_jax.calibration import calibration
from galileo_jax.errors import SceneError
from galileo_jax.physics.model import build_model, object_start_pose
from galileo_jax.scene import load_scene, scene_from_dict


def base() -> dict:
    return yaml.safe_load(open("scenes/ramp_20.yaml"))


@pytest.mark.parametrize("mutate, words", [
    (lambda d: d["camera"].update(pixel_per_metre=3), ["camera.pixel_per_metre", "did you mean 'pixels_per_metre'"]),
    (lambda d: d["objects"][0].update(size=[0.1, 0.1]), ["size", "[length, width, height]"]),
    (lambda d: d["objects"][1].update(shape="cylinder", size=[0.03, 0.04]), ["cannot collide"]),
    (lambda d: d["camera"].pop("pixels_per_metre"), ["pixels_per_metre", "reference"]),
    (lambda d: d["objects"][0].update(mass=-1), ["objects.0.mass"]),
    (lambda d: d.update(objects=[]), ["objects"]),
])
def test_bad_scene_names_the_key(mutate, words):
    d = base()
    mutate(d)
    with pytest.raises(SceneError) as err:
        scene_from_dict(d, "s.yaml")
    msg = str(err.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg, (w, msg)


def test_shipped_scenes_load_and_objects_rest_on_their_surfaces():
    for name in ("ramp_10", "ramp_20", "rollslip_28.3", "bouncing_cart"):
        scene = load_scene(f"scenes/{name}.yaml")
        model, index = build_model(scene)
        assert model.npair >= scene.n_objects
    scene = load_scene("scenes/ramp_20.yaml")
    pos, _ = object_start_pose(scene, 0)
    th = scene.ramp.angle
    # signed distance of object 1's centre from the ramp plane = half its height
    assert math.isclose(pos[0] * math.sin(th) + pos[2] * math.cos(th), scene.objects[0].height / 2, rel_tol=1e-9)


def test_calibration_round_trip_with_roll_and_direction():
    cam = load_scene("scenes/ramp_20.yaml").camera.model_copy(update={"roll_deg": 7.0, "ramp_direction": "left"})
    cal = calibration(cam, anchor_px=(320, 200), anchor_world=(0.1, 0.05))
    world = np.array([[0.3, 0.0], [-0.2, 0.4]])
    assert np.allclose(cal.pixel_to_world(cal.world_to_pixel(world)), world)
    # world +x (down the ramp) points left in the image; up points up (v decreases)
    d = cal.world_to_pixel([[0.2, 0.05]]) - cal.world_to_pixel([[0.1, 0.05]])
    assert d[0, 0] < 0
    d = cal.world_to_pixel([[0.1, 0.15]]) - cal.world_to_pixel([[0.1, 0.05]])
    assert d[0, 1] < 0


def test_a_ramp_board_stated_in_the_scene_is_the_board_the_renderer_draws():
    """ramp.thickness: objects on the ramp start on the board's top face (lifted t along the
    normal), the model's ramp is a box of that thickness, a rendered world board of the same
    thickness gives the same motion exactly, and bad values or a cylinder on a board (MJX cannot
    collide a cylinder with a box) are rejected naming the key."""
    from galileo_jax import synth
    from galileo_jax.physics.model import WorldPhysics

    d = base()
    d["ramp"]["thickness"] = 0.015
    board, flat = scene_from_dict(d), scene_from_dict(base())
    th = board.ramp.angle
    lift = object_start_pose(board, 0)[0] - object_start_pose(flat, 0)[0]
    np.testing.assert_allclose(lift, [0.015 * math.sin(th), 0.0, 0.015 * math.cos(th)], atol=1e-12)
    np.testing.assert_allclose(object_start_pose(board, 1)[0], object_start_pose(flat, 1)[0])  # on the floor
    model, _ = build_model(board)
    ramp = model.geom("ramp")
    assert ramp.type[0] == 6 and ramp.size[2] == pytest.approx(0.0075)  # mjGEOM_BOX, half-thickness
    phys = synth.resolve_params(flat, {"m1": 0.5, "k1": 0.2, "m2": 0.4, "k2": 0.25})
    stated = synth.simulate_motion(board, phys, 240.0, 3, n_frames=300)
    world = synth.simulate_motion(flat, phys, 240.0, 3, n_frames=300, world=WorldPhysics(ramp_thickness=0.015))
    np.testing.assert_array_equal(stated.positions, world.positions)
    from galileo_jax.inference.cnn import scene_hash
    from galileo_jax.scene import scene_key

    assert "thickness" not in scene_key(flat) and "thickness" in scene_key(board)  # old keys and CNN hashes kept
    assert scene_hash(board) != scene_hash(flat)
    assert np.max(np.abs(stated.positions - synth.simulate_motion(flat, phys, 240.0, 3, n_frames=300).positions)) > 0.01
    for value, words in ((-0.01, "ramp.thickness"), (0.5, "ramp.thickness")):
        d["ramp"]["thickness"] = value
        with pytest.raises(SceneError, match=words):
            scene_from_dict(d)
    d["ramp"]["thickness"] = 0.01
    d["objects"][0].update(shape="cylinder", size=[0.03, 0.06])
    d["objects"][1].update(shape="cylinder", size=[0.03, 0.06])
    with pytest.raises(SceneError, match="cylinder on a ramp board"):
        scene_from_dict(d)
