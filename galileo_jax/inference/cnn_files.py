"""Trained CNNs on disk: one folder per model (``model.json`` + Orbax ``weights/``), written
atomically (:func:`save_model`), read back (:func:`load_model`), and found for a scene
(:func:`find_model`) among the shipped models (package data, :data:`MODELS_DIR`), ``./models``
and ``$GALILEO_JAX_MODELS``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from galileo_jax.inference.cnn import (
    FPS_TOLERANCE,
    CNNError,
    CNNSpec,
    TrainedModel,
    build_network,
    scene_hash,
)
from galileo_jax.scene import Scene

#: Folder of the models shipped inside the package (package data, so ``pip install .`` has
#: them too; searched first by :func:`find_model`).
MODELS_DIR = Path(__file__).resolve().parents[1] / "models"


#: Environment variable naming more folders of trained models (``os.pathsep``-separated),
#: searched after :data:`MODELS_DIR` and before ``./models`` (where ``galileo_jax.train``
#: writes by default).
MODELS_ENV = "GALILEO_JAX_MODELS"


def save_model(path: Path, spec: CNNSpec, params, info: dict) -> None:
    """Write a trained model to folder ``path`` atomically: ``model.json`` (spec and training
    record) and ``weights/`` (an Orbax checkpoint of the parameter state). An existing model
    there is replaced only once the new one is complete."""
    import shutil

    import orbax.checkpoint as ocp

    path = Path(path).resolve()
    tmp = path.with_name(path.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    with ocp.StandardCheckpointer() as ckpt:
        ckpt.save(tmp / "weights", jax.tree_util.tree_map(np.asarray, nnx.to_pure_dict(params)))
    (tmp / "model.json").write_text(json.dumps({"spec": spec.to_json(), **info}, indent=1, default=float))
    old = path.with_name(path.name + ".old")
    shutil.rmtree(old, ignore_errors=True)
    if path.exists():
        path.rename(old)
    tmp.rename(path)
    shutil.rmtree(old, ignore_errors=True)


def load_model(path: Path) -> TrainedModel:
    """Load a model folder written by :func:`save_model` (or by ``python -m galileo_jax.train``).

    Raises:
        CNNError: the folder is missing or not a model.
    """
    import orbax.checkpoint as ocp

    path = Path(path).resolve()
    meta = path / "model.json"
    if not meta.is_file():
        raise CNNError(f"{path} is not a trained CNN model (no model.json); train one with python -m galileo_jax.train")
    try:
        info = json.loads(meta.read_text())
        spec = CNNSpec.from_json(info.pop("spec"))
    except (ValueError, KeyError, TypeError) as err:
        raise CNNError(f"{meta} is unreadable ({err}); retrain the model") from None
    graphdef, params = nnx.split(build_network(spec), nnx.Param)
    target = jax.tree_util.tree_map(np.asarray, nnx.to_pure_dict(params))
    try:
        with ocp.StandardCheckpointer() as ckpt:
            restored = ckpt.restore(path / "weights", target)
    except Exception as err:  # noqa: BLE001 - orbax raises many kinds; any means an unusable model
        raise CNNError(f"cannot read the weights in {path / 'weights'} ({type(err).__name__}); retrain the model") from None
    nnx.replace_by_pure_dict(params, jax.tree_util.tree_map(jnp.asarray, restored))
    return TrainedModel(spec, graphdef, params, path, info)


def find_model(scene: Scene, fps: float, path: Path | str | None = None,
               architecture: str | None = None) -> TrainedModel:
    """The trained model for ``scene`` at ``fps``: ``path`` if given, else the first folder
    under :func:`model_dirs` whose spec matches the scene's physics (:func:`~galileo_jax.inference.cnn.scene_hash`) and
    frame rate (within :data:`FPS_TOLERANCE`), preferring the default architecture (and,
    among equals, the earlier folder); where none does, the first scene-conditioned network
    (``spec.family``) whose family holds the scene (:func:`check_family`).

    Raises:
        CNNError: ``path`` does not fit the scene, or no shipped model does (the message says
            how to train one).
        galileo_jax.scene_family.OutOfFamily: only a scene-conditioned network was left, and the
            scene lies outside its family (the message names the input).
    """
    want = scene_hash(scene)
    if path is not None:
        model = load_model(Path(path))
        if model.spec.family is not None:
            check_family(model.spec, scene, fps)
            return model
        if model.spec.scene_hash != want:
            raise CNNError(f"the CNN in {path} was trained on scene {model.spec.scene!r}, whose physics differ "
                           f"from scene {scene.name!r}; train one for this scene (python -m galileo_jax.train)")
        return model
    found, family = [], []
    metas = [m for d in model_dirs() for m in sorted(d.glob("*/model.json"))]
    for order, meta in enumerate(metas):
        try:
            spec = CNNSpec.from_json(json.loads(meta.read_text())["spec"])
        except (ValueError, KeyError, TypeError):
            continue
        if spec.family is not None:
            if architecture in (None, spec.architecture):
                family.append((spec, meta.parent))
        elif spec.scene_hash == want and abs(spec.fps - fps) <= FPS_TOLERANCE * spec.fps \
                and (architecture is None or spec.architecture == architecture):
            found.append((spec.architecture != "profile", order, meta.parent))
    if not found and family:  # a scene-conditioned network serves a scene inside its family
        spec, folder = family[0]
        check_family(spec, scene, fps)
        return load_model(folder)
    if not found:
        raise CNNError(f"no trained CNN matches scene {scene.name!r} at {fps:g} fps; train one: python -m "
                       f"galileo_jax.train --config configs/cnn_ramp20.yaml --scene YOUR_SCENE.yaml --out models/NAME")
    return load_model(sorted(found)[0][2])


def check_family(spec: CNNSpec, scene: Scene, fps: float) -> None:
    """Raise unless ``scene`` filmed at ``fps`` lies inside the family of the scene-conditioned
    network ``spec``.

    Raises:
        galileo_jax.scene_family.OutOfFamily: one line naming the scene's input that is outside
            (or the kind of scene the family does not hold).
    """
    from galileo_jax.scene_family import SceneFamily, scene_features

    SceneFamily.from_dict(spec.family).check(scene_features(scene, fps), f"scene {scene.name!r}")


def model_dirs() -> list[Path]:
    """Folders searched for trained models, in order: the package's own (:data:`MODELS_DIR`),
    those named by ``$GALILEO_JAX_MODELS`` (:data:`MODELS_ENV`), and ``./models``."""
    extra = [Path(p) for p in os.environ.get(MODELS_ENV, "").split(os.pathsep) if p]
    out = []
    for d in [MODELS_DIR, *extra, Path.cwd() / "models"]:
        if d.is_dir() and all(d.resolve() != o.resolve() for o in out):
            out.append(d)
    return out
