"""``facegeom batch JOB.toml``: one operation over many inputs on Dask (see :mod:`facegeom.pipelines.batch`)."""
from __future__ import annotations

import sys

import click


@click.command("batch")
@click.argument("job_file", metavar="JOB.toml", type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(file_okay=False), default=None,
              help="Output folder (default: the job's `output`, relative to the job file).")
@click.option("--scheduler", metavar="ADDRESS", envvar="DASK_SCHEDULER_ADDRESS", default=None,
              help="Run on this Dask scheduler, e.g. tcp://10.0.0.5:8786 (default: $DASK_SCHEDULER_ADDRESS, "
                   "else a local cluster). Its workers need facegeom and the same paths.")
@click.option("--workers", type=click.IntRange(1), default=None,
              help="Worker processes of the local cluster (default: one per core).")
@click.option("--inline", is_flag=True, help="No Dask: run the chunks one after the other in this process.")
@click.option("--isolate", is_flag=True,
              help="With --inline: run each chunk in a forked child process, so an input that crashes the "
                   "process fails alone (its chunk is retried one input per child). The Dask engine isolates "
                   "workers anyway.")
@click.option("--chunk", type=click.IntRange(1), default=None,
              help="Inputs per task (default: the job's [batch] chunk, else 64 landmark files, 16 marker "
                   "frames, 1 otherwise).")
@click.option("--retries", type=click.IntRange(0), default=None,
              help="Retries of a task that raised (default: the job's, else 2). A task whose worker dies is "
                   "rerun by Dask in any case.")
@click.option("--overwrite", is_flag=True, help="Delete existing outputs and recompute every input.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.pass_context
def batch_cmd(ctx, job_file, output, scheduler, workers, inline, isolate, chunk, retries, overwrite, quiet):
    """Run the job in JOB.toml: an operation (fit, drive, retarget, animate, clean) over every input, one
    result file per input and a summary CSV (batch-summary.csv) in the output folder.

    A rerun skips inputs whose outputs exist (every file is written atomically) and redoes failed ones.
    Exit status: 0 when every input succeeded, 1 when some failed (see the summary), 2 for a bad job.

    \b
    Example job (paths relative to the job file):
      operation = "fit"
      method = "sem-ls"
      inputs = "landmarks/*.csv"
      output = "out/fit"
      truth = "truth/{stem}.json"      # optional ground truth per input
      [params]
      clamp = true
      [shared]
      focal = 1000.0
      cx = 320.0
      cy = 240.0
      # identity = true                # one identity per subject folder (identity.npz), then expressions on it
    """
    from facegeom.pipelines.batch import load_job, run_job

    if isolate and not inline:
        raise click.UsageError("--isolate applies to --inline runs (Dask workers are separate processes already)")
    job = load_job(job_file, output=output, data=ctx.obj.data if ctx.obj else None)
    if chunk is not None:
        job.chunk = chunk
    if retries is not None:
        job.retries = retries
    res = run_job(job, scheduler=scheduler, workers=workers, inline=inline, isolate=isolate, overwrite=overwrite,
                  progress=not quiet, echo=click.echo)
    c = res.counts
    line = f"{c['ok']} ok, {c['failed']} failed, {c['skipped']} skipped (already complete)"
    if c.get("not run"):
        line += f", {c['not run']} not run"
    click.echo(f"{line} in {res.seconds:.1f} s -> {res.summary}")
    for r in res.failed[:5]:
        click.echo(f"failed: {r['input']}: {r['message']}", err=True)
    if len(res.failed) > 5:
        click.echo(f"... and {len(res.failed) - 5} more failed inputs (see {res.summary})", err=True)
    if res.failed:
        sys.exit(1)
