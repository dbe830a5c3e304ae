"""Checks of `make test-cluster` (run by run_cluster_test.sh after both runs).

(a) Every job Snakemake planned as a cluster job went through sbatch: the
SLURM job ids Snakemake reported are exactly those in SLURM's job completion
log, each COMPLETED, in the partition the profile took from the environment,
with the CPUs, memory and time limit Snakemake asked for; squeue's comment of
each names the job's rule and wildcards; per rule, as many SLURM jobs as the
dry run planned. The rules the profile sizes ran on the cluster; the others,
the tables and plots among them, did not reach SLURM.
(b) Every table of the cluster run equals the local run's, cell for cell,
timing columns aside, digit for digit (RTOL).
"""
import argparse
import math
import re
import sys
from collections import Counter
from pathlib import Path

import pandas as pd
import yaml

# Wall-clock measurements, which differ between any two runs.
TIMING_TABLES = {"runtime.csv"}
TIMING_COLUMN = re.compile(r"(_seconds|_s|_time)$|^(seconds|s|time)$")
# Numbers equal to this relative difference count as equal: none. Every stage
# is deterministic for a given config and seed (pycolmap numbers the images in
# set order and maps on one thread, open3d registers on one thread), so the
# cluster's tables must be the local run's digit for digit. (Before that,
# open3d's multi-threaded ICP moved Table 2's registration columns by up to
# 1.3e-10, and bundle adjustment without priors by 1e-3 to 1.)
RTOL = 0.0


def parse_jobs(log):
    """The job blocks of a Snakemake log: {jobid: {rule, local, wildcards, threads, resources}}."""
    jobs = {}
    current = None
    for line in Path(log).read_text().splitlines():
        start = re.match(r"^(local)?rule (\w+):$", line)
        if start:
            current = {"rule": start[2], "local": bool(start[1]), "wildcards": [], "threads": 1, "resources": {}}
            continue
        field = re.match(r"^    (\w+): (.*)$", line)
        if not line.startswith("    "):
            current = None
        if current is None or not field:
            continue
        key, value = field[1], field[2]
        if key == "jobid":
            jobs[int(value)] = current
        elif key == "wildcards":
            current["wildcards"] = [item.split("=", 1)[1] for item in value.split(", ")]
        elif key == "threads":
            current["threads"] = int(value)
        elif key == "resources":
            current["resources"] = dict(item.split("=", 1) for item in value.split(", "))
    return jobs


def parse_submissions(log):
    """{SLURM job id: Snakemake job id} from the executor plugin's messages."""
    pattern = re.compile(r"Job (\d+) has been submitted with SLURM jobid (\d+)")
    submissions = {}
    for line in Path(log).read_text().splitlines():
        match = pattern.search(line)
        if match:
            submissions[int(match[2])] = int(match[1])
    return submissions


def parse_jobcomp(path):
    """SLURM's job completion log (jobcomp/filetxt): {job id: {field: value}}."""
    records = {}
    for line in Path(path).read_text().splitlines():
        fields = dict(re.findall(r"(\w+)=(\S*)", line))
        records[int(fields["JobId"])] = fields
    return records


def minutes(limit):
    """SLURM's time limit ('30', 'MM:SS', 'HH:MM:SS' or 'D-HH:MM:SS') in minutes, as a string."""
    if limit.isdigit():
        return limit
    days, _, clock = limit.rpartition("-")
    parts = [int(part) for part in clock.split(":")]
    hours, mins, secs = [0] * (3 - len(parts)) + parts
    return str(int(days or 0) * 1440 + hours * 60 + mins + (secs > 0))


def parse_squeue(path):
    """squeue --format='%i|%j|%T|%k': {job id: (name, state, comment)}."""
    rows = {}
    for line in Path(path).read_text().splitlines():
        job_id, name, state, comment = line.split("|", 3)
        rows[int(job_id)] = (name, state, comment)
    return rows


def check_jobs(args, errors):
    planned = parse_jobs(args.dry_run_log)
    ran = parse_jobs(args.cluster_log)
    submissions = parse_submissions(args.cluster_log)
    jobcomp = parse_jobcomp(args.jobcomp)
    squeue = parse_squeue(args.squeue)

    # The dry run does not mark local jobs; the run's log does ("localrule").
    planned_rules = Counter(job["rule"] for job in planned.values())
    ran_rules = Counter(job["rule"] for job in ran.values())
    local_rules = sorted({job["rule"] for job in ran.values() if job["local"]})
    remote_rules = Counter(job["rule"] for job in ran.values() if not job["local"])
    submitted_rules = Counter(ran[job]["rule"] for job in submissions.values() if job in ran)
    print(f"planned {sum(planned_rules.values())} jobs; ran {sum(remote_rules.values())} as cluster jobs, local rules {local_rules}")
    print(f"Snakemake reported {len(submissions)} sbatch submissions; SLURM's completion log has {len(jobcomp)} jobs")
    if ran_rules != planned_rules:
        errors.append(f"jobs run per rule {dict(ran_rules)} differ from the dry run's plan {dict(planned_rules)}")
    if not submissions:
        errors.append("no job was submitted with sbatch")
    if submitted_rules != remote_rules:
        errors.append(f"sbatch submissions per rule {dict(submitted_rules)} differ from the cluster jobs run {dict(remote_rules)}")
    if set(jobcomp) != set(submissions):
        errors.append(f"SLURM's completion log has jobs {sorted(jobcomp)}, Snakemake submitted {sorted(submissions)}")
    # The rules the profile sizes ran on the cluster, the others locally, the
    # tables and plots among them.
    with open(args.profile) as file:
        sized = set(yaml.safe_load(file)["set-resources"])
    if set(remote_rules) != sized & set(ran_rules) or set(local_rules) & sized:
        errors.append(f"cluster jobs of rules {sorted(remote_rules)}, local {local_rules}; the profile sizes {sorted(sized)}")
    gathering = [rule for rule in ran_rules if rule.startswith(("tabulate_", "plot_")) and rule not in local_rules]
    if gathering:
        errors.append(f"tabulate/plot rules ran as cluster jobs: {gathering}")
    mixed = set(local_rules) & set(remote_rules)
    if mixed:
        errors.append(f"rules run both locally and on the cluster: {sorted(mixed)}")

    run_names = set()
    for slurm_id, jobid in sorted(submissions.items()):
        job = ran[jobid]
        record = jobcomp.get(slurm_id)
        if record is None:
            continue
        run_names.add(record["Name"])
        expected_comment = f"rule_{job['rule']}" + (f"_wildcards_{'_'.join(job['wildcards'])}" if job["wildcards"] else "")
        comment = squeue.get(slurm_id, (None, None, None))[2]
        tres = dict(item.split("=", 1) for item in record["Tres"].split(",") if "=" in item)
        checks = {
            "state": (record["JobState"], "COMPLETED"),
            "exit code": (record["ExitCode"], "0:0"),
            "partition": (record["Partition"], args.partition),
            "partition Snakemake asked for": (job["resources"].get("slurm_partition"), args.partition),
            "comment (rule and wildcards)": (comment, expected_comment),
            "CPUs": (int(record["ProcCnt"]), job["threads"]),
            "memory": (tres.get("mem"), f"{job['resources'].get('mem_mb')}M"),
            "time limit (minutes)": (minutes(record["TimeLimit"]), job["resources"].get("runtime")),
        }
        for what, (got, expected) in checks.items():
            if got != expected:
                errors.append(f"SLURM job {slurm_id} ({job['rule']} {job['wildcards']}): {what} is {got!r}, expected {expected!r}")
    if len(run_names) > 1:
        errors.append(f"the jobs carry more than one run name: {sorted(run_names)}")
    print("sbatch'ed jobs per rule: " + ", ".join(f"{rule} {n}" for rule, n in sorted(submitted_rules.items())))


def check_tables(args, errors):
    local_tables = sorted(path.name for path in (args.local / "results" / "tables").glob("*.csv"))
    cluster_tables = sorted(path.name for path in (args.cluster / "results" / "tables").glob("*.csv"))
    if local_tables != cluster_tables:
        errors.append(f"tables differ: local {local_tables}, cluster {cluster_tables}")
    for name in sorted(set(local_tables) & set(cluster_tables)):
        if name in TIMING_TABLES:
            continue
        # As text: equal means the same digits; numbers that differ in the
        # last digits only (RTOL) are counted and reported.
        local = pd.read_csv(args.local / "results" / "tables" / name, dtype=str, keep_default_na=False)
        cluster = pd.read_csv(args.cluster / "results" / "tables" / name, dtype=str, keep_default_na=False)
        timing = [column for column in local.columns if TIMING_COLUMN.search(column)]
        local, cluster = local.drop(columns=timing), cluster.drop(columns=timing, errors="ignore")
        if list(local.columns) != list(cluster.columns) or local.shape != cluster.shape:
            errors.append(f"{name}: columns or shape differ ({local.shape} vs {cluster.shape})")
            continue
        close, largest = 0, 0.0
        for row, column in zip(*(local != cluster).to_numpy().nonzero()):
            a, b = local.iat[row, column], cluster.iat[row, column]
            relative = relative_difference(a, b)
            if relative <= RTOL:
                close, largest = close + 1, max(largest, relative)
            else:
                errors.append(f"{name} row {row} {local.columns[column]}: local {a}, cluster {b}")
        print(
            f"{name}: {local.shape[0]} rows x {local.shape[1]} columns equal"
            + (f", {close} cells within {RTOL:g} (largest relative difference {largest:.1e}), the rest digit for digit" if close else " digit for digit")
            + (f" (timing columns {timing} left out)" if timing else "")
        )


def relative_difference(a, b):
    """|a - b| / |a| for two numbers; infinite when either is not a number."""
    try:
        x, y = float(a), float(b)
    except ValueError:
        return math.inf
    return abs(x - y) / abs(x) if x else (0.0 if y == 0 else math.inf)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dry-run-log", required=True)
    parser.add_argument("--cluster-log", required=True)
    parser.add_argument("--jobcomp", required=True)
    parser.add_argument("--squeue", required=True)
    parser.add_argument("--partition", required=True)
    parser.add_argument("--profile", required=True, help="the profile's config.v8+.yaml")
    parser.add_argument("--local", type=Path, required=True)
    parser.add_argument("--cluster", type=Path, required=True)
    args = parser.parse_args()
    errors = []
    check_jobs(args, errors)
    check_tables(args, errors)
    for error in errors:
        print(f"FAIL: {error}", file=sys.stderr)
    sys.exit(1 if errors else 0)


if __name__ == "__main__":
    main()
