"""Counts the public items of crates from rustdoc's JSON (format 57): every item reachable from
the crate root through public modules, re-exports, inherent methods, fields and variants, each
item once. Used by scripts/public-items.sh."""
import json, sys, collections
def count(path):
    d = json.load(open(path))
    idx = d["index"]
    seen = set()
    kinds = collections.Counter()
    def visit(i):
        i = str(i)
        if i in seen or i not in idx: return
        seen.add(i)
        it = idx[i]
        if it.get("visibility") != "public" and it.get("crate_id", 0) == 0 and i != str(d["root"]):
            # trait impl items have visibility "default"
            if it.get("visibility") != "default": return
        inner = it["inner"]
        (k, v), = inner.items()
        kinds[k] += 1
        if k == "module":
            for c in v["items"]: visit(c)
        elif k == "use":
            if v.get("id") is not None: visit(v["id"])
        elif k in ("struct", "enum", "union", "trait"):
            for c in v.get("items", []) : visit(c)
            for imp in v.get("impls", []):
                ii = idx.get(str(imp))
                if ii is None: continue
                iv = ii["inner"]["impl"]
                if iv.get("trait") is None:  # inherent impls only
                    for c in iv["items"]: visit(c)
            if k == "struct":
                kind = v["kind"]
                if isinstance(kind, dict) and "plain" in kind:
                    for f in kind["plain"]["fields"]: visit(f)
                elif isinstance(kind, dict) and "tuple" in kind:
                    for f in kind["tuple"]:
                        if f is not None: visit(f)
            if k == "enum":
                for c in v["variants"]: visit(c)
    visit(str(d["root"]))
    return len(seen) - 1, kinds
for p in sys.argv[1:]:
    n, k = count(p)
    print(f"{p.rsplit('/', 1)[-1]}: {n} items {dict(k.most_common())}")
