"""Which NARX configuration's residuals separate the classes better: parallel or series-parallel.

The diagnosis should use the residuals that separate the six classes better. This builds the
whole diagnosis twice with the same recipe and seeds, once per configuration, and scores each
on thrusters neither saw in training (``classifier_eval.window_accuracy``: per-window balanced
accuracy of the raw window answer and of the published decision, four command profiles, six
unseen units):

- parallel (free run): the committed ``models/nominal`` and ``models/classifier``;
- series-parallel (one step ahead from measured outputs): a nominal model made by
  ``scripts/make_nominal_model.sh --mode series-parallel`` (the committed model's data and
  seed) and a classifier made against it by ``scripts/make_classifier_model.sh``.

Writes ``OUT/residual_modes.json`` and ``OUT/residual_modes.md``. About 40 min on 2 idle cores
(two model trainings and two evaluations); ``--reuse`` skips training what ``OUT`` holds.

Usage (after ``. scripts/bootstrap.sh``):
``python scripts/compare_residual_modes.py --out out/residual_modes``
"""

from __future__ import annotations

import argparse
import json
import subprocess
from pathlib import Path

from thruster_fdd.core.diagnosis.model import ClassifierModel
from thruster_fdd.core.nominal.runtime import NominalModel
from thruster_fdd_shore.core.diagnosis.evaluation import WindowEvalConfig, window_accuracy

ROOT = Path(__file__).resolve().parent.parent


def _models(mode: str, out: Path, reuse: bool) -> tuple[Path, Path]:
    """Nominal and classifier folders of one configuration (made if needed)."""
    if mode == "parallel":
        return ROOT / "models" / "nominal", ROOT / "models" / "classifier"
    nominal, classifier = out / mode / "nominal", out / mode / "classifier"
    if not (reuse and (nominal / "model_card.json").is_file()):
        subprocess.run(
            [str(ROOT / "scripts" / "make_nominal_model.sh"), "--mode", mode, str(nominal)],
            check=True,
        )
    if not (reuse and (classifier / "model_card.json").is_file()):
        subprocess.run(
            [str(ROOT / "scripts" / "make_classifier_model.sh"), str(classifier), str(nominal)],
            check=True,
        )
    return nominal, classifier


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/residual_modes"))
    parser.add_argument("--reuse", action="store_true", help="keep models already in OUT")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    cfg = WindowEvalConfig()
    results = {}
    for mode in ("parallel", "series-parallel"):
        nominal_dir, classifier_dir = _models(mode, args.out, args.reuse)
        nominal = NominalModel.load(nominal_dir)
        classifier = ClassifierModel.load(classifier_dir)
        if nominal.card.mode != mode:
            raise SystemExit(f"{nominal_dir} is a {nominal.card.mode} model, not {mode}")
        acc = window_accuracy(cfg, nominal, classifier, progress=True)
        results[mode] = {
            "nominal_model_id": nominal.model_id,
            "classifier_model_id": classifier.model_id,
            **acc,
        }
        (args.out / "residual_modes.json").write_text(json.dumps(results, indent=2))
    lines = [
        "| residuals from | profile | windows | balanced acc. (raw) | balanced acc. (decision) "
        "| unknown (raw) |",
        "|---|---|---|---|---|---|",
    ]
    for mode, r in results.items():
        for name, s in [*r["per_signal"].items(), ("all", r["overall"])]:
            lines.append(
                f"| {mode} | {name} | {s['windows']} | {s['balanced_accuracy']:.4f} | "
                f"{s['balanced_accuracy_stable']:.4f} | {s['unknown_rate']:.3f} |"
            )
    ids = "; ".join(
        f"{m}: {r['nominal_model_id']}, {r['classifier_model_id']}" for m, r in results.items()
    )
    text = "\n".join(lines) + f"\n\nModels: {ids}.\n"
    (args.out / "residual_modes.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
