import csv
import statistics as st
import sys

for tag in sys.argv[1:]:
    r = list(csv.DictReader(open(f"benchmarks/results/carracing/throughput/runs/{tag}/train.csv")))[
        1:
    ]  # the first row holds the initial evaluation
    sps = [float(x["charts/SPS"]) * 8 for x in r]
    ro = [float(x["charts/rollout_SPS"]) * 8 for x in r]
    up = [float(x["charts/update_seconds"]) for x in r]
    print(
        tag,
        "frames/s",
        round(st.median(sps)),
        "rollout frames/s",
        round(st.median(ro)),
        "update s",
        round(st.median(up), 1),
        "rows",
        len(r),
    )
