"""Exported models as files: the folder layout, the model card, digests, the format version
(docs/contracts.md, "Exported model").

An exported model is a folder holding ``model_card.json``, the weights as plain arrays
(``weights.npz``, read with numpy and never unpickled) and the ``torch.export`` program
(``model.pt2``, for tools; the runtime never loads it). The card records the SHA-256 of every
other file; ``load_weights`` checks them all before it reads anything. Both kinds of model
describe their card as a dataclass derived from ``ModelCard``; ``read_card`` checks a card file
against the dataclass's fields and types, so the two kinds cannot drift apart in how strictly
they read (unknown fields, numbers, lists).
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import math
import os
import types
import typing
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from thruster_fdd.core.errors import ModelMismatchError

CARD_FILE = "model_card.json"
"""The model card's file name in an exported model folder."""

PROGRAM_FILE = "model.pt2"
"""The ``torch.export`` program's file name in an exported model folder."""

WEIGHTS_FILE = "weights.npz"
"""The weights' file name: named float64 arrays, the program's own tensors (numpy ``.npz``)."""

FORMAT_VERSION = 2
"""Version of the folder layout and card format this code writes and reads (1: no weights file,
no digests, nominal scaling keyed ``median``/``iqr``)."""

MODELS_ENV = "THRUSTER_FDD_MODELS"
"""Environment variable naming the models folder (``nominal/``, ``classifier/``)."""

CardT = TypeVar("CardT", bound="ModelCard")


@dataclass(frozen=True, kw_only=True)
class ModelCard:
    """The fields every model card has (docs/contracts.md, "Exported model").

    Attributes
    ----------
    kind : str
        ``"nominal"`` or ``"classifier"``.
    model_id : str
        ``<kind>-<architecture>-<hash of the weights>``.
    inputs, outputs : tuple of str
        Signals in and out of the network, in order.
    class_names : tuple of str
        The classes in output order (empty for a nominal model).
    scaling : dict
        ``{signal: {"center": float, "scale": float}}`` in each signal's unit: the network
        sees ``(x - center) / scale``.
    sample_time_s : float
        Sample time of the model's samples, s.
    lookbacks : dict of str to int
        Past samples the model sees (keys by kind).
    architecture : str
    hidden : tuple of int
        Hidden layer sizes.
    training_data_digest : str
        SHA-256 over the training samples.
    training_metrics : dict
        Metrics measured at training.
    code_version : str
        ``thruster_fdd`` version that trained the model.
    created : str
        ISO-8601 UTC time of export.
    files : dict of str to str
        SHA-256 (hex) of every other file of the folder, by file name.
    format_version : int
        ``FORMAT_VERSION`` of the folder.
    extra : dict
        Training options and data summary.
    """

    kind: str
    model_id: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    class_names: tuple[str, ...]
    scaling: dict[str, dict[str, float]]
    sample_time_s: float
    lookbacks: dict[str, int]
    architecture: str
    hidden: tuple[int, ...]
    training_data_digest: str
    training_metrics: dict[str, Any]
    code_version: str
    created: str
    files: dict[str, str] = field(default_factory=dict)
    format_version: int = FORMAT_VERSION
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        """The card as pretty JSON text (tuples as lists)."""
        return json.dumps(dataclasses.asdict(self), indent=2) + "\n"

    def scaling_of(self, names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        """Center and scale arrays, each shape (len(names),), of the named signals.

        Raises
        ------
        ModelMismatchError
            If a signal is missing or its scale is not > 0.
        """
        try:
            center = np.array([self.scaling[n]["center"] for n in names], dtype=float)
            scale = np.array([self.scaling[n]["scale"] for n in names], dtype=float)
        except KeyError as exc:
            raise ModelMismatchError(f"scaling lacks {exc} (signals {list(names)})") from None
        if not np.all(scale > 0):
            raise ModelMismatchError(f"scaling of {list(names)} has a scale <= 0")
        return center, scale


def scaling_entries(
    names: tuple[str, ...], center: np.ndarray, scale: np.ndarray
) -> dict[str, dict[str, float]]:
    """``ModelCard.scaling`` entries of the named signals."""
    return {
        n: {"center": float(c), "scale": float(s)}
        for n, c, s in zip(names, center, scale, strict=True)
    }


def default_models_dir() -> Path:
    """The models folder: ``$THRUSTER_FDD_MODELS``, else ``models/`` of the source workspace.

    The workspace root is found by walking up from this file to the folder that holds
    ``thruster_fdd_msgs/`` (colcon's symlink install keeps the sources' location); outside a
    workspace it is ``./models``.
    """
    env = os.environ.get(MODELS_ENV)
    if env:
        return Path(env)
    for parent in Path(__file__).resolve().parents:
        if (parent / "thruster_fdd_msgs").is_dir() and (parent / "models").is_dir():
            return parent / "models"
    return Path("models")


def _convert(value: Any, hint: Any, where: str) -> Any:
    """``value`` (parsed JSON) as the dataclass field type ``hint``; ModelMismatchError if it is
    not of that type. bool is never a number; numbers must be finite."""
    origin = typing.get_origin(hint)
    if hint is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        for option in typing.get_args(hint):
            try:
                return _convert(value, option, where)
            except ModelMismatchError:
                continue
        raise ModelMismatchError(f"{where} has type {type(value).__name__}")
    if hint is float or hint is int:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        if hint is int:
            ok = ok and isinstance(value, int)
        if not ok:
            raise ModelMismatchError(f"{where} has type {type(value).__name__}, expected {hint}")
        if not math.isfinite(value):
            raise ModelMismatchError(f"{where} is {value!r}, expected a finite number")
        return hint(value)
    if hint is str:
        if not isinstance(value, str):
            raise ModelMismatchError(f"{where} has type {type(value).__name__}, expected str")
        return value
    if origin is tuple:
        if not isinstance(value, list):
            raise ModelMismatchError(f"{where} has type {type(value).__name__}, expected list")
        item = typing.get_args(hint)[0]
        return tuple(_convert(v, item, f"{where}[{i}]") for i, v in enumerate(value))
    if origin is dict:
        if not isinstance(value, dict):
            raise ModelMismatchError(f"{where} has type {type(value).__name__}, expected object")
        _, item = typing.get_args(hint)
        return {k: _convert(v, item, f"{where}.{k}") for k, v in value.items()}
    raise TypeError(f"card field type {hint!r} is not supported")


MAX_CARD_BYTES = 1 << 20
"""Largest model card file read (the shipped cards: a few KB); a larger one is refused unread."""


def read_card(model_dir: str | Path, card_type: type[CardT], kind: str) -> CardT:
    """Read ``model_dir/model_card.json`` into ``card_type``, checking every field.

    Parameters
    ----------
    model_dir : str or Path
        Exported model folder.
    card_type : type
        A frozen dataclass whose fields (names and types) are the card's; fields with a default
        may be absent.
    kind : str
        The card's ``kind`` must equal it (checked first, so another kind of model is named
        as such rather than by its first odd field).

    Returns
    -------
    card_type
        The card, with JSON lists as tuples and numbers as the field's type.

    Raises
    ------
    ModelMismatchError
        Naming the file and what is wrong: missing, not JSON, not an object, another kind or
        format version, a missing, unknown or mistyped field, a non-finite number; a file larger
        than ``MAX_CARD_BYTES`` or nested too deep to parse.
    """
    path = Path(model_dir) / CARD_FILE
    if not path.is_file():
        raise ModelMismatchError(f"{path}: model card missing")
    try:
        with path.open("rb") as f:
            data = f.read(MAX_CARD_BYTES + 1)
    except OSError as exc:
        raise ModelMismatchError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    if len(data) > MAX_CARD_BYTES:
        raise ModelMismatchError(f"{path}: larger than {MAX_CARD_BYTES} bytes, not a model card")
    try:
        raw = json.loads(data.decode("utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ModelMismatchError(f"{path}: not valid JSON ({exc})") from exc
    except RecursionError:
        raise ModelMismatchError(f"{path}: nested too deep, not a model card") from None
    if not isinstance(raw, dict):
        raise ModelMismatchError(f"{path}: expected a JSON object, got {type(raw).__name__}")
    if raw.get("kind") != kind:
        raise ModelMismatchError(f"{path}: kind is {raw.get('kind')!r}, expected {kind!r}")
    if raw.get("format_version", FORMAT_VERSION) != FORMAT_VERSION:
        raise ModelMismatchError(
            f"{path}: format_version is {raw.get('format_version')!r}, expected {FORMAT_VERSION}"
        )
    fields = {f.name: f for f in dataclasses.fields(card_type)}
    hints = typing.get_type_hints(card_type)
    unknown = sorted(set(raw) - set(fields))
    if unknown:
        raise ModelMismatchError(f"{path}: unknown field(s) {', '.join(unknown)}")
    required = [
        name
        for name, f in fields.items()
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    missing = [name for name in required if name not in raw]
    if missing:
        raise ModelMismatchError(f"{path}: missing field(s) {', '.join(missing)}")
    values = {}
    for name, value in raw.items():
        try:
            values[name] = _convert(value, hints[name], f"field {name!r}")
        except ModelMismatchError as exc:
            raise ModelMismatchError(f"{path}: {exc}") from None
    return card_type(**values)


def file_sha256(path: str | Path) -> str:
    """SHA-256 (hex) of a file's bytes."""
    h = hashlib.sha256()
    with Path(path).open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def weights_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """``arrays`` as the bytes of a ``weights.npz`` (float64, no pickled objects)."""
    buf = io.BytesIO()
    np.savez(buf, **{k: np.asarray(v, dtype=np.float64) for k, v in arrays.items()})
    return buf.getvalue()


def check_files(model_dir: str | Path, card: ModelCard) -> None:
    """ModelMismatchError naming the file unless every file the card lists is there with its
    recorded SHA-256, and the weights file is among them."""
    model_dir = Path(model_dir)
    if WEIGHTS_FILE not in card.files:
        raise ModelMismatchError(f"{model_dir / CARD_FILE}: lists no {WEIGHTS_FILE}")
    for name, digest in card.files.items():
        path = model_dir / name
        if Path(name).name != name:
            raise ModelMismatchError(f"{model_dir / CARD_FILE}: file name {name!r} is a path")
        if not path.is_file():
            raise ModelMismatchError(f"{path}: missing")
        if file_sha256(path) != digest:
            raise ModelMismatchError(
                f"{path}: SHA-256 differs from the one {CARD_FILE} records (changed or damaged)"
            )


MAX_WEIGHTS_BYTES = 64 << 20
"""Largest unpacked size of a weights file's arrays (the shipped models: under 100 KB); a larger
one is refused before anything is decompressed."""


def _member_array_bytes(archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> int:
    """Bytes the array in one ``.npy`` member of a weights archive claims, read from its header
    (before numpy allocates it); ValueError when the header is not one of a plain array or the
    claim exceeds what the member holds."""
    with archive.open(info) as member:
        version = np.lib.format.read_magic(member)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(member)
        elif version in ((2, 0), (3, 0)):
            shape, _, dtype = np.lib.format.read_array_header_2_0(member)
        else:
            raise ValueError(f"{info.filename}: .npy format version {version}")
    if dtype.hasobject:
        raise ValueError(f"{info.filename}: object arrays are refused")
    claimed = math.prod(shape) * dtype.itemsize
    if claimed > info.file_size:
        raise ValueError(
            f"{info.filename}: header claims {claimed} bytes, the member holds {info.file_size}"
        )
    return claimed


def load_weights(model_dir: str | Path, card: ModelCard) -> dict[str, np.ndarray]:
    """The named weight arrays (float64) of an exported model, after ``check_files``.

    Raises
    ------
    ModelMismatchError
        Naming the file: a listed file missing or changed, or a weights file that is not an
        ``.npz`` of plain numeric arrays (pickled objects are refused, never loaded), unpacks
        to more than ``MAX_WEIGHTS_BYTES`` or has an array header claiming more data than its
        member holds (checked from the headers, before any array is allocated).
    """
    check_files(model_dir, card)
    path = Path(model_dir) / WEIGHTS_FILE
    try:
        with zipfile.ZipFile(path) as archive:
            members = archive.infolist()
            size = sum(info.file_size for info in members)
            if size > MAX_WEIGHTS_BYTES:
                raise ModelMismatchError(
                    f"{path}: {size} bytes of arrays unpacked, more than {MAX_WEIGHTS_BYTES}"
                )
            for info in members:
                _member_array_bytes(archive, info)
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: np.array(npz[k], dtype=np.float64) for k in npz.files}
    except (OSError, ValueError, zipfile.BadZipFile, TypeError, EOFError) as exc:
        raise ModelMismatchError(f"{path}: not a weights file of numeric arrays ({exc})") from exc
    bad = [k for k, v in arrays.items() if not np.all(np.isfinite(v))]
    if bad:
        raise ModelMismatchError(f"{path}: non-finite values in {', '.join(bad)}")
    return arrays


def data_digest(arrays: list[np.ndarray]) -> str:
    """SHA-256 (hex) over float64 arrays, each shape (n, k), in order."""
    h = hashlib.sha256()
    for arr in arrays:
        h.update(np.ascontiguousarray(arr, dtype=np.float64).tobytes())
    return h.hexdigest()


def code_version() -> str:
    """``thruster_fdd <version>`` of the installed package."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"thruster_fdd {version('thruster_fdd')}"
    except PackageNotFoundError:
        return "thruster_fdd unknown"
