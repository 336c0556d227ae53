"""`edgepick replay`: a `pick --record` recording's choices made again, without the robot (click only)."""

from __future__ import annotations

import json

import click

from edgepick.cli.options import choice
from edgepick.runtime.engine import Engine


@click.command()
@click.argument("recording", type=click.Path(dir_okay=False))
@click.option("--model", default=None, type=click.Path(dir_okay=False),
              help="Segment the recorded colour frames with this ONNX model first [default: the grasp step runs on "
                   "the label maps the run's model gave].")
@click.option("--threads", default=2, show_default=True, help="Inference threads (--model).")
@click.option("--engine", default=Engine.ONNXRUNTIME.value, show_default=True, type=choice(Engine),
              help="Inference engine (--model).")
def replay(recording: str, model: str | None, threads: int, engine: Engine) -> None:
    """Rerun the grasp step on RECORDING (made by `edgepick pick --record`) and print what each cycle
    would choose now beside what it chose.

    With the recorded labels, the same depth, calibration, pick settings and arm pose give the
    same choice: a recording explains its run, and grasp changes can be tried on a failed
    session's frames. With --model, a new model is tried on the same frames (stored as JPEG, so
    it sees a little compression noise). One line per cycle on stderr; the JSON summary on stdout.
    Exit status 0 whether or not the choices agree: `same` in the summary says which did.
    """
    from edgepick.robot.replay import open_recording
    from edgepick.robot.replay import replay as replay_cycles
    from edgepick.runtime.session import Segmenter

    rec = open_recording(recording)
    segmenter = Segmenter(model, threads=threads, engine=engine) if model else None
    results = []
    for r in replay_cycles(rec, segmenter):
        was, now = r["recorded"], r["replayed"]
        then = f"{was['target']} at {was['pixel']}" if was["target"] else "nothing"
        chosen = f"{now['target']} at {now['pixel']}" if now["target"] else f"nothing ({now['reason']})"
        shift = f" ({r['shift_px']:.2f} px apart)" if r["shift_px"] else ""
        where = ""
        if "round" in r:  # a clutter-removal round: the table it picked from and what the pick left
            w = r["round"]
            where = f" (round {w['round']}, pick {w['pick']}: {w['parts_before']} parts, {w['parts_after']} after)"
        click.echo(f"cycle {r['cycle']}{where}: recorded {then}; replay {chosen}{shift}"
                   f"{'' if r['same'] else '  <- differs'}", err=True)
        results.append(r)
    click.echo(json.dumps({"recording": recording, "model": model or rec.metadata.get("model"),
                           "labels": "model" if model else "recorded", "cycles": len(results),
                           "same": sum(r["same"] for r in results), "results": results}, indent=1))
