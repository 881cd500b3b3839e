#!/usr/bin/env python3
"""Read a study's shard files in pyarrow and check them against docs/studies.md.

    python3 tools/parquet_check.py MANIFEST [OTHER_MANIFEST]

For every shard of MANIFEST (shard-IIIII-of-KKKKK.parquet beside it): the columns, in
order, with the types of the documented schema (written out here from the table in
docs/studies.md, not taken from twinmill); the key-value metadata `twinmill.study` (the
manifest's id) and `twinmill.shards`; one row per trial of the shard, in trial order, with
the manifest's inputs. With OTHER_MANIFEST (the same study planned with another shard
count and run), the rows of both, read through pyarrow, are equal but for `shard` and
`seconds`. Prints one line per file; exit status 1 and the reason on the first mismatch.
Needs pyarrow.
"""

import json
import os
import sys

import pyarrow as pa
import pyarrow.parquet as pq


def documented_schema(m):
    """The columns and types of docs/studies.md's table for manifest m."""
    cols = [
        ("trial", pa.uint64()),
        ("shard", pa.uint64()),
        ("scanner_seed", pa.uint64()),
        ("noise_sigma_mm", pa.float64()),
    ]
    cols += [("in." + d, pa.float64()) for d in m["varied"]]
    for p in m["parameters"]:
        cols += [
            (p + ".value", pa.float64()),
            (p + ".sigma", pa.float64()),
            (p + ".injected", pa.float64()),
            (p + ".determined", pa.bool_()),
        ]
    cols += [
        ("chi2", pa.float64()),
        ("dof", pa.uint64()),
        ("rounds", pa.uint64()),
        ("converged", pa.bool_()),
        ("error", pa.string()),
        ("seconds", pa.float64()),
    ]
    return cols


def fail(msg):
    print("parquet_check: " + msg, file=sys.stderr)
    sys.exit(1)


def read_study(manifest_path):
    """The rows of every shard of the manifest (checked), as a list of dicts."""
    with open(manifest_path, encoding="utf-8") as f:
        m = json.load(f)
    folder = os.path.dirname(os.path.abspath(manifest_path))
    want = documented_schema(m)
    k = m["shards"]
    rows = []
    for i in range(k):
        path = os.path.join(folder, "shard-%05d-of-%05d.parquet" % (i, k))
        table = pq.read_table(path)
        have = [(f.name, f.type) for f in table.schema]
        if have != want:
            fail("%s: columns %s, documented %s" % (path, have, want))
        meta = {
            key.decode(): value.decode()
            for key, value in (table.schema.metadata or {}).items()
        }
        if meta.get("twinmill.study") != m["id"]:
            fail("%s: twinmill.study %r, manifest %r" % (path, meta.get("twinmill.study"), m["id"]))
        if meta.get("twinmill.shards") != str(k):
            fail("%s: twinmill.shards %r, manifest %d" % (path, meta.get("twinmill.shards"), k))
        trials = [t for t in m["trials"] if t["shard"] == i]
        got = table.to_pylist()
        if [r["trial"] for r in got] != [t["trial"] for t in trials]:
            fail("%s: trials %s, manifest %s" % (path, [r["trial"] for r in got], [t["trial"] for t in trials]))
        for r, t in zip(got, trials):
            inputs = {"in." + name: value for name, value in t["deviations"]}
            for key, value in [("shard", i), ("scanner_seed", t["scanner_seed"]),
                               ("noise_sigma_mm", t["noise_sigma_mm"])] + list(inputs.items()):
                if r[key] != value:
                    fail("%s: trial %d: %s = %r, manifest %r" % (path, t["trial"], key, r[key], value))
            for p in m["parameters"]:
                determined = r[p + ".value"] is not None
                if r[p + ".determined"] != determined or (r[p + ".sigma"] is None) == determined:
                    fail("%s: trial %d: %s.determined disagrees with its value and sigma" % (path, t["trial"], p))
                if determined and not r[p + ".sigma"] > 0:
                    fail("%s: trial %d: %s.sigma %r" % (path, t["trial"], p, r[p + ".sigma"]))
            if r["error"] is None and r["chi2"] is None:
                fail("%s: trial %d: neither an error nor a chi2" % (path, t["trial"]))
        print("%s: %d rows, %d columns, the documented schema" % (os.path.basename(path), len(got), len(have)))
        rows += got
    return rows


def main():
    if len(sys.argv) not in (2, 3):
        fail("usage: parquet_check.py MANIFEST [OTHER_MANIFEST]")
    rows = read_study(sys.argv[1])
    if len(sys.argv) == 3:
        other = read_study(sys.argv[2])
        strip = lambda rs: [{k: v for k, v in r.items() if k not in ("shard", "seconds")} for r in rs]
        a, b = strip(rows), strip(other)
        if len(a) != len(b):
            fail("%d rows against %d" % (len(a), len(b)))
        for x, y in zip(a, b):
            if x != y:
                diff = sorted(k for k in x if x[k] != y[k])
                fail("trial %d differs in %s" % (x["trial"], diff))
        print("%d rows equal to the other plan's (shard and seconds aside)" % len(a))


if __name__ == "__main__":
    main()
