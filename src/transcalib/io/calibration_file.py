"""``calibration.json`` + ``arrays.npz``: a saved :class:`~transcalib.types.Calibration`.

The JSON holds everything small and human-readable (schema version, software version,
camera, uncertainty, diagnostics, options, statistics, timings, a summary of the inputs);
everything that grows with the number of points (points, their standard deviations,
residuals, inlier flags, the linear estimate's depths, point ids) goes to a binary
sidecar ``arrays.npz`` beside it, so the JSON stays a few kB at any n and both load fast.
``load_calibration(save_calibration(c)) == c`` in every field, bit for bit. The schema is
documented in ``docs/formats.md``.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields, is_dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np

from ..errors import Diagnostic, InputError
from .files import atomic_write, jsonable
from .ids import point_id_array

__all__ = ["check_calibration", "save_calibration", "load_calibration", "load_saved"]

#: Version of the ``calibration.json`` schema; bumped on any incompatible change. Version 1
#: kept the statistics and some estimates in one ``info`` dict; it is still read.
SCHEMA_VERSION = 2
JSON_NAME = "calibration.json"
ARRAYS_NAME = "arrays.npz"


@dataclass(frozen=True, eq=False)
class Saved:
    """A saved calibration with what the file says about its inputs.

    Attributes
    ----------
    calibration : Calibration
    point_ids : (n_points,) int64 or str array, or None   ids of the points, when saved
    inputs : dict                      the ``inputs`` section (view ids, file names, counts)
    document : dict                    the whole JSON document
    """

    calibration: object
    point_ids: np.ndarray | None
    inputs: dict
    document: dict


def calibration_paths(path) -> tuple[Path, Path]:
    """``(json_path, arrays_path)`` for ``path``: a folder (``calibration.json`` and
    ``arrays.npz`` in it) or a ``.json`` file (sidecar ``<stem>.arrays.npz``, or
    ``arrays.npz`` for ``calibration.json``)."""
    path = Path(path)
    if path.suffix.lower() != ".json":
        return path / JSON_NAME, path / ARRAYS_NAME
    sidecar = ARRAYS_NAME if path.name == JSON_NAME else f"{path.stem}.arrays.npz"
    return path, path.with_name(sidecar)


# --------------------------------------------------------------------------------------
# encoding of values that plain JSON cannot hold exactly
# --------------------------------------------------------------------------------------


def _tagged(value):
    """Exact JSON form of statistics (``info``): arrays and non-finite floats are tagged."""
    if isinstance(value, dict):
        return {str(k): _tagged(v) for k, v in value.items()}
    if isinstance(value, tuple):
        return {"__tuple__": [_tagged(v) for v in value]}
    if isinstance(value, list):
        return [_tagged(v) for v in value]
    if isinstance(value, np.ndarray):
        return {"__ndarray__": _tagged(value.ravel().tolist()), "dtype": value.dtype.str, "shape": list(value.shape)}
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (np.integer, int)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if math.isfinite(v) else {"__float__": repr(v)}
    if value is None or isinstance(value, str):
        return value
    raise InputError(f"cannot save a value of type {type(value).__name__} in a calibration file: {value!r}")


def _untagged(value):
    if isinstance(value, list):
        return [_untagged(v) for v in value]
    if not isinstance(value, dict):
        return value
    if "__float__" in value:
        return float(value["__float__"])
    if "__tuple__" in value:
        return tuple(_untagged(v) for v in value["__tuple__"])
    if "__ndarray__" in value:
        flat = [np.nan if v is None else _untagged(v) for v in value["__ndarray__"]]
        return np.array(flat, dtype=np.dtype(value["dtype"])).reshape(value["shape"])
    return {k: _untagged(v) for k, v in value.items()}


def _matrix(value, shape=None) -> np.ndarray:
    """Nested lists from JSON (null = NaN) as a float array."""
    a = np.array(jsonable(value) if value is not None else [], dtype=object)
    a = np.where(a == None, np.nan, a).astype(float)  # noqa: E711 (element-wise None test)
    return a.reshape(shape) if shape is not None else a


def _float(value) -> float:
    return float("nan") if value is None else float(value)


# --------------------------------------------------------------------------------------
# options (frozen dataclasses, nested)
# --------------------------------------------------------------------------------------


def _options_to_json(options) -> dict | None:
    if options is None:
        return None
    out = {}
    for f in fields(options):
        v = getattr(options, f.name)
        if is_dataclass(v):
            out[f.name] = _options_to_json(v)
        elif isinstance(v, MappingProxyType):
            out[f.name] = dict(v)
        else:
            out[f.name] = _tagged(v)
    return out


def _options_from_json(doc: dict | None):
    if doc is None:
        return None
    from ..types import CalibrateOptions, RansacOptions, RefineOptions

    def build(cls, d, **nested):
        unknown = sorted(set(d) - {f.name for f in fields(cls)})
        if unknown:
            raise InputError(f"calibration file: unknown option(s) {', '.join(unknown)} in {cls.__name__}; "
                             "it was written by a newer transcalib")
        return cls(**{k: _untagged(v) for k, v in d.items() if k not in nested}, **nested)

    return build(CalibrateOptions, doc, ransac=build(RansacOptions, doc.get("ransac", {})),
                 refinement=build(RefineOptions, doc.get("refinement", {})))


# --------------------------------------------------------------------------------------
# typed statistics and estimates
# --------------------------------------------------------------------------------------


def _stats_to_json(stats) -> dict:
    """:class:`~transcalib.types.CalibrationStats` as exact JSON (non-finite floats tagged)."""
    return _tagged({"stages": tuple(stats.stages), "timings_s": dict(stats.timings_s),
                    "ransac": None if stats.ransac is None else asdict(stats.ransac),
                    "refine": None if stats.refine is None else asdict(stats.refine),
                    "subset": None if stats.subset is None else asdict(stats.subset),
                    "distortion_selection": [asdict(d) for d in stats.distortion_selection],
                    "sigma_truncation_factor": stats.sigma_truncation_factor})


def _stats_from_json(doc: dict):
    from ..types import CalibrationStats, DistortionStep, RansacStats, RefineStats

    d = _untagged(doc)

    def make(cls, value):
        return None if value is None else cls(**value)

    return CalibrationStats(stages=tuple(d["stages"]), timings_s=d["timings_s"], ransac=make(RansacStats, d["ransac"]),
                            refine=make(RefineStats, d["refine"]), subset=make(RefineStats, d["subset"]),
                            distortion_selection=tuple(DistortionStep(**x) for x in d["distortion_selection"]),
                            sigma_truncation_factor=d["sigma_truncation_factor"])


#: The fields of a hand-eye pose that are arrays.
_HAND_EYE_ARRAYS = ("R", "t", "R_std_deg", "t_cov", "undetermined", "session_of_view")


def _estimates_to_json(cal) -> dict:
    """The estimates beside the camera (each None when not estimated): refined
    translations' std, the robot's pose error, view rotations, the flange rotations and
    the hand-eye pose."""
    vr, he, re, un = cal.view_rotations, cal.hand_eye, cal.robot_error, cal.uncertainty
    return _tagged({
        "T_std": cal.T_std,
        "robot_error": None if re is None else {f.name: getattr(re, f.name) for f in fields(re)},
        "uncertainty": None if un is None else {f.name: _plain_field(getattr(un, f.name)) for f in fields(un)},
        "view_rotations": None if vr is None else {"deg": vr.deg, "std_deg": vr.std_deg, "chi2": vr.chi2},
        "flange_rotations": cal.flange_rotations,
        "hand_eye": None if he is None else {"setup": he.setup, **{k: np.asarray(getattr(he, k)) for k in
                                                                  _HAND_EYE_ARRAYS},
                                             "session_labels": list(he.session_labels), "notes": list(he.notes)}})


def _plain_field(v):
    """A field of :class:`~transcalib.types.Uncertainty` as JSON-able values."""
    if isinstance(v, MappingProxyType):
        return dict(v)
    if is_dataclass(v):
        return {f.name: getattr(v, f.name) for f in fields(v)}
    return v


def _estimates_from_json(doc: dict) -> dict:
    from ..types import HandEye, RobotError, SessionErrorEstimate, Uncertainty, ViewFieldEstimate, ViewRotations

    d = _untagged(doc)
    vr, he, re, un = d["view_rotations"], d["hand_eye"], d.get("robot_error"), d.get("uncertainty")
    if un is not None and un.get("view_field") is not None:
        un = {**un, "view_field": ViewFieldEstimate(**un["view_field"])}
    if un is not None and un.get("session_error") is not None:
        un = {**un, "session_error": SessionErrorEstimate(**un["session_error"])}
    return {"T_std": d["T_std"], "flange_rotations": d["flange_rotations"],
            "robot_error": None if re is None else RobotError(**re),
            "uncertainty": None if un is None else Uncertainty(**un),
            "view_rotations": None if vr is None else ViewRotations(vr["deg"], vr["std_deg"], vr["chi2"]),
            "hand_eye": None if he is None else HandEye(**{**he, "session_labels": tuple(he["session_labels"]),
                                                           "notes": tuple(he["notes"])})}


def _typed_fields(doc: dict) -> dict:
    """``stats``, ``info`` and the estimates beside the camera, from either schema."""
    if doc["schema_version"] == 1:
        return _from_version_1(_untagged(doc["info"]))
    return {"stats": _stats_from_json(doc["stats"]), "info": _untagged(doc["info"]),
            **_estimates_from_json(doc["estimates"])}


#: Keys of a version-1 ``info`` dict that were statistics of the refinement.
_V1_REFINE = ("iterations", "cost", "stop_reason", "converged", "dof", "n_observations", "n_points_used",
              "n_points_excluded", "n_points_behind_camera", "n_points_undetermined", "inlier_threshold_px", "time_s")


def _from_version_1(info: dict) -> dict:
    """The typed fields of a schema-1 file, whose ``info`` dict held them all."""
    from ..types import CalibrationStats, DistortionStep, RefineStats, ViewRotations

    info = dict(info)
    refine = {k: info.pop(k) for k in _V1_REFINE if k in info}
    info.pop("stage", None)
    rot = [info.pop(f"view_rotations{k}", None) for k in ("_deg", "_std_deg", "_chi2")]
    stats = CalibrationStats(
        stages=tuple(info.pop("stages", ())),
        timings_s={k: info.pop(k) for k in [k for k in info if k.endswith("_s") and np.isscalar(info[k])]},
        refine=RefineStats(**refine) if len(refine) == len(_V1_REFINE) else None,
        distortion_selection=tuple(DistortionStep(**d) for d in info.pop("distortion_selection", ())),
        sigma_truncation_factor=info.pop("sigma_truncation_factor", None))
    info.pop("subset", None)  # the flange offset of the old sessions model stays in info: no rotations were saved
    return {"stats": stats, "T_std": info.pop("T_std", None), "info": info,
            "view_rotations": None if rot[0] is None else ViewRotations(*rot)}


# --------------------------------------------------------------------------------------
# save
# --------------------------------------------------------------------------------------


def _summary(cal, point_ids, inputs) -> dict:
    seen = np.isfinite(cal.residuals_px[..., 0])
    out = {
        "n_views": cal.n_views,
        "n_points": cal.n_points,
        "n_observations_with_residual": int(seen.sum()),
        "n_points_reconstructed": int(np.isfinite(cal.X[:, 0]).sum()),
        "n_inliers": None if cal.inliers is None else int(np.sum(cal.inliers)),
        "has_point_ids": point_ids is not None,
    }
    out.update(jsonable(dict(inputs or {})))
    return out


def _arrays(cal, point_ids) -> dict:
    arrays = {"X": cal.X, "residuals_px": cal.residuals_px}
    if cal.X_std is not None:
        arrays["X_std"] = cal.X_std
    if cal.inliers is not None:
        arrays["inliers"] = np.asarray(cal.inliers)
    if cal.linear is not None:
        arrays.update(linear_X=cal.linear.X, linear_depth=cal.linear.depth, linear_used=np.asarray(cal.linear.used))
        if cal.linear.static is not None:
            arrays["linear_static"] = np.asarray(cal.linear.static)
    if point_ids is not None:
        ids = point_id_array(point_ids)
        if ids.shape != (cal.n_points,):
            raise InputError(f"point_ids: {ids.size} ids for {cal.n_points} points")
        arrays["point_ids"] = ids
    return arrays


def _document(cal, point_ids, inputs, arrays_name: str, arrays: dict) -> dict:
    from .files import software_version

    cam = cal.camera
    lin = cal.linear
    unit = cal.options.unit if cal.options is not None else None
    return {
        "schema_version": SCHEMA_VERSION,
        "software": {"name": "transcalib", "version": software_version()},
        "unit": unit,
        "n_views": cal.n_views,
        "n_points": cal.n_points,
        "image_size": None if cam.image_size is None else list(cam.image_size),
        "K": cam.K.tolist(),
        "R_cam_world": cam.R.tolist(),
        "dist_model": cam.dist_model,
        "dist": cam.dist.tolist(),
        "dist_opencv": cam.dist5.tolist(),
        "rms_px": jsonable(cal.rms_px),
        "sigma_px": jsonable(cal.sigma_px),
        "T": cal.T.tolist(),
        "param_names": list(cal.param_names),
        "std": {k: jsonable(v) for k, v in cal.std.items()},
        "cov": None if cal.cov is None else jsonable(cal.cov),
        "diagnostics": [{"code": getattr(d, "code", ""), "message": str(d)} for d in cal.diagnostics],
        "linear": None if lin is None else {
            "K": lin.K.tolist(), "R": lin.R.tolist(), "A": lin.A.tolist(),
            "singular_values": jsonable(lin.singular_values), "n_used_points": int(lin.n_used_points),
            "method": lin.method,
        },
        "options": _options_to_json(cal.options),
        "estimates": _estimates_to_json(cal),
        "stats": _stats_to_json(cal.stats),
        "info": _tagged(dict(cal.info)),
        "inputs": _summary(cal, point_ids, inputs),
        "arrays": {"file": arrays_name,
                   "contents": {k: {"shape": list(v.shape), "dtype": v.dtype.str} for k, v in arrays.items()}},
    }


def check_calibration(cal, caller: str) -> None:
    """:class:`InputError` unless ``cal`` is a :class:`~transcalib.types.Calibration`
    (what ``transcalib.<caller>`` writes)."""
    from ..types import Calibration

    if not isinstance(cal, Calibration):
        raise InputError(f"transcalib.{caller}: expected a Calibration (what transcalib.calibrate returns), "
                         f"got {type(cal).__name__}")


def save_calibration(cal, path, *, point_ids=None, inputs: dict | None = None) -> tuple[Path, Path]:
    """Write ``cal`` as ``calibration.json`` and its sidecar ``arrays.npz``, atomically:
    :func:`transcalib.save`; :func:`transcalib.load` reads it back, equal in every field.

    Parameters
    ----------
    cal : Calibration
    path : path-like
        A folder (created if missing) or a ``.json`` file name (:func:`calibration_paths`).
    point_ids : (n_points,) sequence, optional
        Ids of the points, saved in the sidecar as int64 when every id is an integer,
        else as text (:func:`~transcalib.io.ids.point_id_array`), returned by
        :func:`load_saved`.
    inputs : dict, optional
        JSON-able summary of the inputs (file names, view ids, ...) for the ``inputs``
        section.

    Returns
    -------
    (json_path, arrays_path)

    Raises
    ------
    InputError
        ``cal`` is not a Calibration.
    """
    check_calibration(cal, "save")
    json_path, arrays_path = calibration_paths(path)
    arrays = _arrays(cal, point_ids)
    doc = _document(cal, point_ids, inputs, arrays_path.name, arrays)
    text = json.dumps(doc, indent=2, allow_nan=False) + "\n"
    with atomic_write(arrays_path, "wb") as fh:  # sidecar first: the JSON names a complete file
        np.savez(fh, **arrays)
    with atomic_write(json_path, encoding="utf-8", newline="\n") as fh:
        fh.write(text)
    return json_path, arrays_path


# --------------------------------------------------------------------------------------
# load
# --------------------------------------------------------------------------------------


def _read(path) -> tuple[dict, dict]:
    json_path, _ = calibration_paths(path)
    if not json_path.is_file():
        raise InputError(f"no saved calibration at {str(path)!r}: {str(json_path)!r} does not exist")
    try:
        doc = json.loads(json_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{str(json_path)!r} is not a calibration file (not JSON: {exc})") from None
    version = doc.get("schema_version") if isinstance(doc, dict) else None
    if version is None:
        raise InputError(f"{str(json_path)!r} has no schema_version: not a calibration file of transcalib >= 0.2")
    if version > SCHEMA_VERSION:
        raise InputError(f"{str(json_path)!r} has schema_version {version}; this transcalib reads up to "
                         f"{SCHEMA_VERSION}: upgrade transcalib")
    arrays_path = json_path.with_name(doc["arrays"]["file"])
    if not arrays_path.is_file():
        raise InputError(f"{str(json_path)!r} needs its sidecar {str(arrays_path)!r}, which does not exist; "
                         "copy both files together")
    with np.load(arrays_path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return doc, arrays


def _linear(doc, arrays):
    from ..types import LinearEstimate

    lin = doc["linear"]
    if lin is None:
        return None
    return LinearEstimate(
        K=_matrix(lin["K"]), R=_matrix(lin["R"]), A=_matrix(lin["A"]), X=arrays["linear_X"],
        depth=arrays["linear_depth"], singular_values=_matrix(lin["singular_values"]),
        n_used_points=int(lin["n_used_points"]), used=arrays["linear_used"], method=lin["method"],
        static=arrays["linear_static"] if "linear_static" in arrays else None)


def load_saved(path) -> Saved:
    """Read a calibration saved by :func:`save_calibration`, with its point ids and inputs.

    Parameters
    ----------
    path : path-like
        The folder, or the ``.json`` file.

    Raises
    ------
    InputError
        Missing or foreign file, a newer schema, a missing sidecar.
    """
    from ..geometry.camera import Camera
    from ..types import Calibration

    doc, arrays = _read(path)
    camera = Camera(K=_matrix(doc["K"]), R=_matrix(doc["R_cam_world"]), dist=_matrix(doc["dist"]),
                    dist_model=doc["dist_model"],
                    image_size=None if doc["image_size"] is None else tuple(doc["image_size"]))
    cal = Calibration(
        camera=camera, X=arrays["X"], residuals_px=arrays["residuals_px"], rms_px=_float(doc["rms_px"]),
        T=_matrix(doc["T"]), sigma_px=None if doc["sigma_px"] is None else float(doc["sigma_px"]),
        diagnostics=[Diagnostic(d["code"], d["message"]) for d in doc["diagnostics"]],
        linear=_linear(doc, arrays), cov=None if doc["cov"] is None else _matrix(doc["cov"]),
        std={k: _float(v) for k, v in doc["std"].items()}, param_names=tuple(doc["param_names"]),
        X_std=arrays.get("X_std"), inliers=arrays.get("inliers"), options=_options_from_json(doc["options"]),
        **_typed_fields(doc),
    )
    return Saved(cal, arrays.get("point_ids"), doc.get("inputs", {}), doc)


def load_calibration(path):
    """Read a :class:`~transcalib.types.Calibration` saved by :func:`save_calibration`
    (``transcalib.load``): equal to the saved one in every field.

    Parameters
    ----------
    path : path-like
        The folder holding ``calibration.json`` and ``arrays.npz``, or the ``.json`` file.
    """
    return load_saved(path).calibration
