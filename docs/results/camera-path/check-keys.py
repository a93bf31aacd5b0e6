"""How far each key of keys.json is from the frame of cameras.json that should be it (a loop of
len(keys) - 1 spans over the frames: key k is frame k * frames / spans). Prints one line a key."""
import json

keys = json.load(open("keys.json"))["frames"]
frames = json.load(open("cameras.json"))["frames"]
spans = len(keys) - 1
for k in range(spans):
    f = k * len(frames) // spans
    a, b = keys[k]["transform_matrix"], frames[f]["transform_matrix"]
    print(f"key {k} -> frame {f}: largest pose difference {max(abs(a[r][c] - b[r][c]) for r in range(3) for c in range(4)):.1e}")
