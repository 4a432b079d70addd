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
    """The [record] table a pattern training run needs
    (gyrodiag_harness.campaigns.pattern_learning)."""
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
    """The three FMU instances (DTG, injector, Diagnoser)."""
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
    header = ("# DTG pattern-classifier TRAINING run (python -m gyrodiag_harness learn-signatures "
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


def _expect(kind: str, **fields: object) -> str:
    lines = ["[[expect]]", f'kind = "{kind}"']
    for key, value in fields.items():
        if isinstance(value, str):
            lines.append(f'{key} = "{value}"')
        elif isinstance(value, bool):
            lines.append(f"{key} = {'true' if value else 'false'}")
        else:
            lines.append(f"{key} = {value!r}")
    return "\n".join(lines) + "\n"


VERIFY_HEADER = (
    "# DTG pattern classifier (the Diagnoser's default). Chain of the seed DTG scenarios:\n"
    "# DTG FMU (paper set, 1 V dither, 1 mV pick-off noise, case at rest) -> FaultInjector\n"
    "# -> Diagnoser at 1 kHz (forgetting RLS 0.999, reference learned and checked over\n"
    "# 1-5 s, residual tests against it, classes of the library learned from\n"
    "# scenarios/training/patterns: python -m gyrodiag_harness learn-signatures\n"
    "# scenarios/training/patterns --out <out>/dtg_patterns.json, then verify with --out\n"
    "# <out>). Generated by scenarios/generate_dtg_pattern.py.\n")
FILES = 'files = { "dtg.signature_file" = "${out}/dtg_patterns.json" }'
A = "diag.dtg.alarm"
CODE = "diag.dtg.fault_code"


def verification_files() -> dict[str, str]:
    """The pattern classifier's verification scenarios (seeds 301+)."""
    codes = {n: i + 1 for i, n in enumerate(class_names())}
    out: dict[str, str] = {}
    extra = (A, CODE, "diag.dtg.fault_type", "diag.dtg.fault_signal", "diag.dtg.fault_axis",
             "diag.dtg.fault_size", "diag.dtg.fault_rate", "diag.dtg.fault_ratio",
             "diag.dtg.class_distance", "diag.dtg.reference_valid",
             "diag.dtg.learning")

    def scenario(name: str, comment: str, desc: str, duration: float, seed: int,
                 faults: str, expects: list[str], diag: str = DIAG) -> None:
        text = (VERIFY_HEADER + comment + f'name = "{name}"\ndescription = "{desc}"\n'
                f"duration_s = {duration!r}\nstep_s = 0.001\n\n"
                + fmus(seed, seed + 100, diag=diag, files=FILES) + CHAIN + "\n" + faults
                + "\n" + record_block(extra=extra) + "\n" + "\n".join(expects))
        out[name] = text

    scenario(
        "dtg_pattern_uty_step",
        "# A 0.3 V step on the y pick-off: detected at once, classified uty_step (code 2) on\n"
        "# the y axis with its size; the paper's rule gave it the x-axis class.\n",
        "0.3 V step on Uty at 6 s: class uty_step, axis y, size 0.3 V", 9.0, 301,
        injector_fault("uty_step", "Uty", "step", 0.3, 6.0),
        [_expect("no_alarm_before", signal=A),
         _expect("detected_within", signal=A, fault="uty_step", max_delay_s=0.1),
         _expect("value_at_end", name="class uty_step", signal=CODE, equals=codes["uty_step"]),
         _expect("value_at_end", name="axis y", signal="diag.dtg.fault_axis", equals=2),
         _expect("value_at_end", name="type step", signal="diag.dtg.fault_type", equals=1),
         _expect("value_at_end", name="size", signal="diag.dtg.fault_size", min=0.25,
                 max=0.35),
         _expect("value_at_end", name="reference valid", signal="diag.dtg.reference_valid",
                 equals=1)])
    for sig, onset, seed in (("Uy", 6.0, 303), ("Ux", 7.0, 305)):
        name = f"{sig.lower()}_drift"
        axis = 2 if sig == "Uy" else 1
        scenario(
            f"dtg_pattern_{name}_slow",
            f"# A slow drift, 0.1 V/s, of the {sig} torquer read-out: detected within 3 s\n"
            "# (the paper's rule: not within 1.5 s), classified a drift once the residual\n"
            "# level is seen growing, with its rate.\n",
            f"0.1 V/s drift on {sig} at {onset:g} s: detected within 3 s, class {name}",
            onset + 3.0, seed, injector_fault(name, sig, "drift", 0.1, onset),
            [_expect("no_alarm_before", signal=A),
             _expect("detected_within", signal=A, fault=name, max_delay_s=3.0),
             _expect("value_at_end", name=f"class {name}", signal=CODE, equals=codes[name]),
             _expect("value_at_end", name="axis", signal="diag.dtg.fault_axis", equals=axis),
             _expect("value_at_end", name="rate", signal="diag.dtg.fault_rate", min=0.07,
                     max=0.13)])
    scenario(
        "dtg_pattern_utx_step_persistent",
        "# Alarm memory: a 0.3 V pick-off step held for 64 s keeps the alarm at every\n"
        "# sample (the paper's forgetting estimator let it go after 4-5 s).\n",
        "0.3 V step on Utx at 6 s held to 70 s: alarm held >= 60 s, class utx_step", 70.0, 307,
        injector_fault("utx_step", "Utx", "step", 0.3, 6.0),
        [_expect("no_alarm_before", signal=A),
         _expect("detected_within", signal=A, fault="utx_step", max_delay_s=0.1),
         _expect("value_in_window", name="alarm held 6.1-70 s", signal=A, t0_s=6.1,
                 t1_s=70.0, min=1),
         _expect("value_in_window", name="class utx_step 7-70 s", signal=CODE, t0_s=7.0,
                 t1_s=70.0, min=codes["utx_step"], max=codes["utx_step"])])
    scenario(
        "dtg_pattern_utx_noise_intermittent",
        "# An intermittent fault: 0.3 V of noise on Utx from 6 to 8 s. The alarm holds\n"
        "# while the noise lasts and clears within the stated time after it goes: the\n"
        "# long variance window (2 s) and the clear time (0.5 s) of the residual tests,\n"
        "# or the fast estimator's return into the ratio band if that takes longer\n"
        "# (measured; docs/notes.md).\n",
        "0.3 V noise on Utx 6-8 s: alarm 6-8 s, cleared by 11 s", 13.0, 309,
        injector_fault("utx_noise", "Utx", "noise", 0.3, 6.0, end=8.0),
        [_expect("no_alarm_before", signal=A),
         _expect("detected_within", signal=A, fault="utx_noise", max_delay_s=0.1),
         _expect("value_in_window", name="alarm while the noise lasts", signal=A, t0_s=6.1,
                 t1_s=8.0, min=1),
         _expect("value_in_window", name="class utx_noise 7-8 s", signal=CODE, t0_s=7.0,
                 t1_s=8.0, min=codes["utx_noise"], max=codes["utx_noise"]),
         _expect("value_in_window", name="cleared 3 s after the noise", signal=A,
                 t0_s=11.0, t1_s=13.0, max=0)])
    scenario(
        "dtg_pattern_fault_in_learning",
        "# A fault that starts inside the learning window (1-5 s): 0.3 V step on Utx at\n"
        "# 3 s. The guarded learning finds the change, fits the reference on the segments\n"
        "# before it (dtg.reference_status 2) and the residual tests alarm at the end of\n"
        "# learning, no later than 0.5 s after it (here at once).\n",
        "0.3 V step on Utx at 3 s, inside learning: flagged at 5 s, class utx_step", 9.0,
        311, injector_fault("utx_step", "Utx", "step", 0.3, 3.0),
        [_expect("value_at", name="reference flagged at 5.5 s",
                 signal="diag.dtg.reference_status", t_s=5.5, equals=2),
         _expect("value_at", name="alarm by 5.5 s", signal=A, t_s=5.5, equals=1),
         _expect("value_in_window", name="alarm held 5.5-9 s", signal=A, t0_s=5.5,
                 t1_s=9.0, min=1),
         _expect("value_at_end", name="class utx_step", signal=CODE,
                 equals=codes["utx_step"])])
    scenario(
        "dtg_pattern_fault_before_learning",
        "# A fault present from before the learning window (0.3 V step on Uty from\n"
        "# 0.5 s): nothing changes inside the window, the nominal prior of the library\n"
        "# (fault-free training runs) rejects the learned reference and replaces it\n"
        "# (dtg.reference_status 3); the residual tests against the prior alarm at 5 s.\n",
        "0.3 V step on Uty from 0.5 s: prior mismatch, class uty_step", 9.0, 313,
        injector_fault("uty_step", "Uty", "step", 0.3, 0.5),
        [_expect("value_at", name="prior mismatch at 5.5 s",
                 signal="diag.dtg.reference_status", t_s=5.5, equals=3),
         _expect("value_at", name="alarm by 5.5 s", signal=A, t_s=5.5, equals=1),
         _expect("value_at_end", name="class uty_step", signal=CODE,
                 equals=codes["uty_step"])])
    scenario(
        "dtg_pattern_nominal",
        "# Fault-free, 60 s: no alarm, reference valid (the false-alarm witness of the\n"
        "# scenario set; the campaign measures hours).\n",
        "nominal 60 s: no alarm, reference valid", 60.0, 315, "",
        [_expect("no_alarm_before", signal=A, t_s=60.0),
         _expect("value_at_end", name="reference valid", signal="diag.dtg.reference_valid",
                 equals=1)])
    fine = DIAG.replace('"dtg.forgetting" = 0.999', '"dtg.forgetting" = 0.9998').replace(
        '"dtg.learn_start_s" = 1.0, "dtg.learn_end_s" = 5.0',
        '"dtg.learn_start_s" = 2.0, "dtg.learn_end_s" = 10.0, "dtg.low" = 0.93, '
        '"dtg.high" = 1.07')
    scenario(
        "dtg_pattern_spin_slowdown",
        "# A physical fault: the spin motor slows to 85 % at 12 s. The residuals barely\n"
        "# change (theta3, theta4 move together); the fine ratio band of\n"
        "# dtg_physical_spin_slowdown.toml (forgetting 0.9998, band 0.93/1.07) alarms and\n"
        "# the alarm is classified against the physical classes: spin (code 17), both\n"
        "# axes, with the estimated spin ratio.\n",
        "spin 85 % at 12 s: ratio-band alarm, class spin, ratio ~0.85", 24.0, 317,
        '[[faults]]\nname = "spin"\nset = "dtg.spin_fraction"\nvalue = 0.85\nstart_s = 12.0\n',
        [_expect("no_alarm_before", signal=A),
         _expect("detected_within", signal=A, fault="spin", max_delay_s=8.0),
         _expect("value_at_end", name="class spin", signal=CODE, equals=codes["spin"]),
         _expect("value_at_end", name="both axes", signal="diag.dtg.fault_axis", equals=3),
         _expect("value_at_end", name="ratio", signal="diag.dtg.fault_ratio", min=0.8,
                 max=0.9)], diag=fine)
    return out


def main() -> None:
    TRAINING.mkdir(parents=True, exist_ok=True)
    for old in TRAINING.glob("dtg_pattern_train_*.toml"):
        old.unlink()
    for name, text in training_files().items():
        (TRAINING / f"{name}.toml").write_text(text, encoding="utf-8")
    print(f"wrote {len(training_files())} training scenarios to {TRAINING}")
    for old in HERE.glob("dtg_pattern_*.toml"):
        old.unlink()
    for name, text in verification_files().items():
        (HERE / f"{name}.toml").write_text(text, encoding="utf-8")
    print(f"wrote {len(verification_files())} verification scenarios to {HERE}")


if __name__ == "__main__":
    main()
