"""Write the DTG pattern-classifier scenarios (training set and verification scenarios).

    .venv/bin/python scenarios/generate_dtg_pattern.py

The files are committed; this script is how they were made and how to change them
consistently. Every scenario uses the chain of the seed DTG scenarios: DTG FMU (paper
parameter set, 1 V white torquer dither, 1 mV pick-off noise, case at rest) ->
FaultInjector (all four signals, one step of latency each) -> Diagnoser DTG channel at
1 kHz with the default pattern classifier (forgetting RLS 0.999, reference learned over
1-5 s).

Training set (scenarios/training/patterns/): every fault type on every signal at three
sizes (none of them a campaign size: 0.2, 0.6, 2 V or V/s for steps and drifts, signs
alternating), the physical faults at two sizes, two nominal runs; seeds 5000+ (DTG) and
6000+ (injector), disjoint from the seed scenarios (7-203) and from campaign seeds (hashes
checked by tests/test_dtg_pattern_scenarios.py). Faults start at 8 s, a long window after
the end of learning, so that every run also feeds the noise model; runs end 3 s after
the onset, the time at which the campaign judges the class.
"""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
TRAINING = HERE / "training" / "patterns"

SIGNALS = ("Utx", "Uty", "Ux", "Uy")
CHANNEL = {"Utx": 1, "Uty": 2, "Ux": 3, "Uy": 4}
#: Class order = fault codes: 4·(type − 1) + signal, then the physical classes.
TYPES = ("step", "noise", "loss", "drift")
INJECTOR_TYPE = {"step": "step", "drift": "ramp", "noise": "noise", "loss": "signal_loss"}
SIZE_KEY = {"step": "magnitude", "drift": "magnitude", "noise": "noise_std",
            "loss": "noise_std"}
#: Training sizes per (type, pick-off or torquer signal).
TRAIN_SIZES = {
    ("step", "pickoff"): [0.2, -0.6, 2.0], ("step", "torquer"): [0.2, -0.6, 2.0],
    ("drift", "pickoff"): [0.2, -0.6, 2.0], ("drift", "torquer"): [0.2, -0.6, 2.0],
    ("noise", "pickoff"): [0.05, 0.2, 2.0], ("noise", "torquer"): [0.6, 1.2, 2.5],
    # loss: the noise left on the lost signal, below the signal's own spread (pick-offs
    # ~0.01 V, torquers ~1 V): above it a loss is a noise fault for every statistic
    ("loss", "pickoff"): [0.0, 0.001, 0.003], ("loss", "torquer"): [0.0, 0.01, 0.1],
}
PHYSICAL = {"spin": ("dtg.spin_fraction", [0.8, 0.6]),
            "torquer": ("dtg.torquer_scale", [0.8, 0.6])}
ONSET_S = 8.0
POST_ONSET_S = 3.0

DIAG = ('parameters = { sample_period_s = 1e-3, "grey.enabled" = false, '
        '"df.enabled" = false, "dtg.estimator" = 2, "dtg.forgetting" = 0.999, '
        '"dtg.learn_start_s" = 1.0, "dtg.learn_end_s" = 5.0 }')

CHAIN = '''
[[connections]]
from = "dtg.Utx"
to = "injector.in_1"

[[connections]]
from = "dtg.Uty"
to = "injector.in_2"

[[connections]]
from = "dtg.Ux"
to = "injector.in_3"

[[connections]]
from = "dtg.Uy"
to = "injector.in_4"

[[connections]]
from = "injector.out_1"
to = "diag.dtg.Utx"

[[connections]]
from = "injector.out_2"
to = "diag.dtg.Uty"

[[connections]]
from = "injector.out_3"
to = "diag.dtg.Ux"

[[connections]]
from = "injector.out_4"
to = "diag.dtg.Uy"
'''


def class_names() -> list[str]:
    """Class names in code order."""
    names = [f"{s.lower()}_{t}" for t in TYPES for s in SIGNALS]
    return [*names, "spin", "torquer"]


def record_block(d: str = "diag", extra: tuple[str, ...] = ()) -> str:
    """The [record] table a pattern training run needs (harness.campaigns.pattern_learning)."""
    names = [f"{d}.dtg.alarm", f"{d}.dtg.residual_alarm", f"{d}.dtg.level_growth",
             f"{d}.dtg.stat_window_s", f"{d}.dtg.reference_status"]
    names += [f"{d}.dtg.level[{i}]" for i in range(1, 7)]
    names += [f"{d}.dtg.log_var_ratio[{i}]" for i in range(1, 7)]
    names += [f"{d}.dtg.eta_{a}[{i}]" for a in "xy" for i in range(1, 6)]
    names += [f"{d}.dtg.ref_theta0[{i}]" for i in range(1, 6)]
    for key in ("ref_mean", "ref_block_std", "ref_var_short", "ref_var_long"):
        names += [f"{d}.dtg.{key}[{i}]" for i in range(1, 7)]
    names += list(extra)
    lines = ",\n".join(f'    "{n}"' for n in names)
    return f"[record]\nvariables = [\n{lines},\n]\n"


def fmus(dtg_seed: int, injector_seed: int, diag: str = DIAG, files: str = "") -> str:
    text = (f'[fmus.dtg]\nfmu = "DTG"\nparameters = {{ parameter_set = 1, seed = {dtg_seed}, '
            f'noise_std = 1e-3, dither_std = 1.0 }}\n\n'
            f'[fmus.injector]\nfmu = "FaultInjector"\nparameters = {{ seed = {injector_seed} }}\n\n'
            f'[fmus.diag]\nfmu = "Diagnoser"\n{diag}\n')
    if files:
        text += f"{files}\n"
    return text


def injector_fault(name: str, signal: str, typ: str, size: float, start: float,
                   end: float | None = None) -> str:
    text = (f'[[faults]]\nname = "{name}"\ninjector = "injector"\nchannel = {CHANNEL[signal]}\n'
            f'type = "{INJECTOR_TYPE[typ]}"\n{SIZE_KEY[typ]} = {size!r}\nstart_s = {start!r}\n')
    if end is not None:
        text += f"end_s = {end!r}\n"
    return text


def training_files() -> dict[str, str]:
    files: dict[str, str] = {}
    codes = {n: i + 1 for i, n in enumerate(class_names())}
    k = 0
    header = ("# DTG pattern-classifier TRAINING run (python -m harness learn-signatures "
              "scenarios/training/patterns).\n# Generated by scenarios/generate_dtg_pattern.py; "
              "see its docstring for the chain and the seeds.\n")
    for typ in TYPES:
        for signal in SIGNALS:
            kind = "pickoff" if signal in ("Utx", "Uty") else "torquer"
            for j, size in enumerate(TRAIN_SIZES[typ, kind], start=1):
                k += 1
                name = f"{signal.lower()}_{typ}"
                scen = f"dtg_pattern_train_{name}_t{j}"
                unit = "V/s" if typ == "drift" else "V"
                desc = f"{typ} on {signal}, size {size:g} {unit}, from {ONSET_S:g} s"
                files[scen] = (
                    header + f'name = "{scen}"\ndescription = "{desc}"\n'
                    f"duration_s = {ONSET_S + POST_ONSET_S!r}\nstep_s = 0.001\n\n"
                    + fmus(5000 + k, 6000 + k) + CHAIN + "\n"
                    + injector_fault(name, signal, typ, size, ONSET_S) + "\n"
                    + record_block() + "\n"
                    f'[training]\nclassifier = "pattern"\nsignature = "{name}"\n'
                    f'code = {codes[name]}\ntype = "{typ}"\nsignal = "{signal}"\n'
                    f'fault = "{name}"\ndiagnoser = "diag"\n')
    for cls, (param, sizes) in PHYSICAL.items():
        for j, size in enumerate(sizes, start=1):
            k += 1
            scen = f"dtg_pattern_train_{cls}_t{j}"
            files[scen] = (
                header + f'name = "{scen}"\n'
                f'description = "physical fault {param} = {size:g} from {ONSET_S:g} s"\n'
                f"duration_s = {ONSET_S + POST_ONSET_S + 4.0!r}\nstep_s = 0.001\n\n"
                + fmus(5000 + k, 6000 + k) + CHAIN + "\n"
                f'[[faults]]\nname = "{cls}"\nset = "{param}"\nvalue = {size!r}\n'
                f"start_s = {ONSET_S!r}\n\n"
                + record_block() + "\n"
                f'[training]\nclassifier = "pattern"\nsignature = "{cls}"\n'
                f'code = {codes[cls]}\ntype = "{cls}"\nfault = "{cls}"\ndiagnoser = "diag"\n')
    for j in (1, 2):
        k += 1
        scen = f"dtg_pattern_train_nominal_t{j}"
        files[scen] = (
            header + f'name = "{scen}"\ndescription = "nominal, 30 s (noise model and prior)"\n'
            "duration_s = 30.0\nstep_s = 0.001\n\n"
            + fmus(5000 + k, 6000 + k) + CHAIN + "\n" + record_block() + "\n"
            '[training]\nclassifier = "pattern"\nsignature = "nominal"\ncode = 0\n'
            'type = "nominal"\ndiagnoser = "diag"\n')
    return files


def main() -> None:
    TRAINING.mkdir(parents=True, exist_ok=True)
    for old in TRAINING.glob("dtg_pattern_train_*.toml"):
        old.unlink()
    for name, text in training_files().items():
        (TRAINING / f"{name}.toml").write_text(text, encoding="utf-8")
    print(f"wrote {len(training_files())} training scenarios to {TRAINING}")


if __name__ == "__main__":
    main()
