"""Each run's training PSNR (the mean of the logged batches in windows of 2,000 steps) and its
held-out PSNR (val_psnr) from metrics.csv files: `python3 curves.py RUN/metrics.csv ...`."""
import csv
import sys

for path in sys.argv[1:]:
    windows, held_out = {}, []
    for row in csv.DictReader(open(path)):
        step = int(row["step"])
        if row["psnr"]:
            windows.setdefault(step // 2000, []).append(float(row["psnr"]))
        if row.get("val_psnr"):
            held_out.append((step + 1, float(row["val_psnr"])))
    print(path)
    print("  train", " ".join(f"{(k + 1) * 2}k:{sum(v) / len(v):.2f}" for k, v in sorted(windows.items())))
    print("  held-out", " ".join(f"{s // 1000}k:{v:.2f}" for s, v in held_out))
