"""python3 -m flsh.batch SPEC.json [--scheduler ADDRESS] [--workers N] [--out DIR] [--redo]
[--dry-run]: runs a batch spec (docs/batch.md).

Exit status: 0 every job done (or done before), 1 some jobs failed (see manifest.jsonl),
2 a bad spec or option (nothing written), 130 interrupted (Ctrl-C)."""
import argparse
import sys

from .errors import BatchError, SpecError

PROG = "python3 -m flsh.batch"


def parse_args(argv):
    parser = argparse.ArgumentParser(
        prog=PROG, description="Runs the simulations of a batch spec on a Dask cluster and "
                               "writes their outputs, a manifest and a data set index.")
    parser.add_argument("spec", metavar="SPEC.json", help="batch spec file (docs/batch.md)")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="address of a running Dask scheduler (default: a local cluster)")
    parser.add_argument("--workers", metavar="N", type=int,
                        help="worker processes of the local cluster (default: the core count)")
    parser.add_argument("--out", metavar="DIR",
                        help='output folder (default: the spec\'s "out", else '
                             "out/batch/SPEC_NAME), relative to the working directory")
    parser.add_argument("--redo", action="store_true",
                        help="run every job again, also those done before")
    parser.add_argument("--dry-run", action="store_true",
                        help="check the spec and list the jobs and what would run; run nothing")
    args = parser.parse_args(argv)
    if args.workers is not None and args.scheduler is not None:
        parser.error("--workers: only for the local cluster (the workers of --scheduler are "
                     "started with `dask worker`)")
    if args.workers is not None and args.workers < 1:
        parser.error(f"--workers: expected at least 1, got {args.workers}")
    return args


def print_plan(plan, redo):
    from .runner import plan_status

    todo, skipped, _ = plan_status(plan, redo)
    run = {job.id for job in todo}
    for job in plan.jobs:
        print(f"{'run ' if job.id in run else 'skip'}  {job.id}  ({job.simulation}, "
              f"{job.motion or 'no motion'}, {job.spec_hash[:12]})")
    print(f"{len(plan.jobs)} job(s): {len(todo)} to run, {len(skipped)} done before; "
          f"output {plan.out_dir}, avatar cache {plan.cache_dir}")


def main(argv=None):
    args = parse_args(argv)
    try:
        from .load import load_spec

        plan = load_spec(args.spec, out=args.out)
        if args.dry_run:
            print_plan(plan, args.redo)
            return 0
        from .cluster import open_client
        from .folders import check_unlocked
        from .runner import run_batch

        check_unlocked(plan.out_dir)
        with open_client(args.scheduler, args.workers) as client:
            summary = run_batch(plan, client, redo=args.redo)
    except (SpecError, BatchError) as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\n{PROG}: interrupted: the jobs that finished are in manifest.jsonl and "
              "index.json; run the same command again to run the others", file=sys.stderr)
        return 130
    print(summary.table(), file=sys.stderr)
    return 1 if summary.failed else 0


if __name__ == "__main__":
    sys.exit(main())
