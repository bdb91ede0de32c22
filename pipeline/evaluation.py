"""Segmentation and association quality against SemanticKITTI ground truth.

Objects are keyed as the issue defines: thing classes (person, car, cyclist) by class and
instance, stuff classes (trunk, bush, building, unknown, ground) by class alone. A segment's
dominant object is the key holding most of its points.

- purity: point-weighted share of a segment's points that belong to its dominant object;
- pure_fraction: share of segments with purity >= 0.95;
- over_segmentation: segments per (frame, object) among objects that dominate a segment;
- association precision: links whose two segments share a dominant object;
- association recall: consecutive-frame presences of an instance (>= 30 points in both frames)
  that a link joins: the two linked segments each hold >= 5 of the instance's points and are each
  dominated by the instance's key (the instance itself for things, its class for stuff).

Segments here are the sampled segments (track id > 0 in `tracks/*.label`).
Everything is also reported per class (of the dominant object) and per range bin.

`quality_summary` gives the four headline numbers used to choose the perception defaults on real
scans: purity with ground and unlabelled points left out, thing cover (per person, car or
cyclist instance of >= 30 points in a frame, the share of all its points in its largest segment,
averaged over instances), link precision and thing link recall.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.classes import CLASS_INDEX, GROUND, PAPER, POINT_CLASSES, UNLABELLED, to_ours

# the truth is read in the default set's classes; its things (person, car, cyclist) have instances
THING_NAMES = tuple(c.name for c in PAPER.point_classes if c.kind == "thing")
THINGS = tuple(CLASS_INDEX[name] for name in THING_NAMES)
RANGE_BINS = (0.0, 15.0, 30.0, 50.0, np.inf)
RANGE_NAMES = ("0-15", "15-30", "30-50", "50+")
MIN_PRESENCE_POINTS = 30
MIN_MEMBER_POINTS = 5


def object_keys(semantic: np.ndarray, instance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(class-or-instance key, instance key) per point, int64: class << 16 | instance.

    The first keys stuff by class alone; the second always includes the instance.
    """
    cls = to_ours(semantic).astype(np.int64)
    inst = instance.astype(np.int64)
    full = (cls << 16) | inst
    thing = np.isin(cls, THINGS)
    return np.where(thing, full, cls << 16), full


@dataclass
class _Acc:
    seg_points: list[np.ndarray] = field(default_factory=list)
    seg_dominant: list[np.ndarray] = field(default_factory=list)
    seg_class: list[np.ndarray] = field(default_factory=list)
    seg_range: list[np.ndarray] = field(default_factory=list)
    overseg: list[np.ndarray] = field(default_factory=list)
    link_ok: list[np.ndarray] = field(default_factory=list)
    link_class: list[np.ndarray] = field(default_factory=list)
    link_range: list[np.ndarray] = field(default_factory=list)
    rec_hit: list[np.ndarray] = field(default_factory=list)
    rec_class: list[np.ndarray] = field(default_factory=list)
    rec_range: list[np.ndarray] = field(default_factory=list)


@dataclass(frozen=True)
class FrameTruth:
    """Per-frame inputs: track: (N,) uint32 track id per point (0 = none); key, inst_key: (N,) int64
    (see `object_keys`); points: (N, 3) float32."""

    track: np.ndarray
    key: np.ndarray
    inst_key: np.ndarray
    points: np.ndarray


def _segments(ft: FrameTruth) -> dict[str, np.ndarray]:
    m = ft.track > 0
    tid = ft.track[m].astype(np.int64)
    comb = (tid << 24) | (ft.key[m] & 0xFFFFFF)
    u, cnt = np.unique(comb, return_counts=True)
    seg = u >> 24
    # dominant key per segment: the key with the largest count among the segment's rows
    order = np.lexsort((-cnt, seg))
    u, cnt, seg = u[order], cnt[order], seg[order]
    first = np.ones(len(seg), bool)
    first[1:] = seg[1:] != seg[:-1]
    ids = seg[first]
    dom = u[first] & 0xFFFFFF
    dom_cnt = cnt[first]
    total = np.add.reduceat(cnt, np.flatnonzero(first)) if len(cnt) else cnt
    # dominant instance key, and the segment's range
    ucomb, icnt = np.unique((tid << 24) | (ft.inst_key[m] & 0xFFFFFF), return_counts=True)
    iseg = ucomb >> 24
    order = np.lexsort((-icnt, iseg))
    ucomb, iseg = ucomb[order], iseg[order]
    ifirst = np.ones(len(iseg), bool)
    ifirst[1:] = iseg[1:] != iseg[:-1]
    dom_inst = ucomb[ifirst] & 0xFFFFFF  # same segment order as `ids` (both sorted by id)
    members = ucomb[icnt[order] >= MIN_MEMBER_POINTS] if len(ucomb) else ucomb  # tid << 24 | inst key
    pos = np.searchsorted(ids, tid)
    rng = np.zeros(len(ids))
    np.add.at(rng, pos, np.linalg.norm(ft.points[m], axis=1))
    rng /= np.maximum(total, 1)
    return {"ids": ids, "dom": dom, "dom_cnt": dom_cnt, "total": total, "dom_inst": dom_inst, "range": rng,
            "members": members}


def _linked_objects(a: dict, b: dict, tids: np.ndarray) -> np.ndarray:
    """Instance keys joined by the links `tids` between segment tables a (frame t) and b (t + 1)."""
    found = []
    for tid in tids:
        ia = a["members"][(a["members"] >> 24) == tid] & 0xFFFFFF
        ib = b["members"][(b["members"] >> 24) == tid] & 0xFFFFFF
        both = np.intersect1d(ia, ib)
        if len(both) == 0:
            continue
        dom_a = a["dom"][np.searchsorted(a["ids"], tid)]
        dom_b = b["dom"][np.searchsorted(b["ids"], tid)]
        cls = both >> 16
        key = np.where(np.isin(cls, THINGS), both, cls << 16)
        found.append(both[(key == dom_a) & (key == dom_b)])
    return np.concatenate(found) if found else np.zeros(0, np.int64)


def _range_bin(r: np.ndarray) -> np.ndarray:
    return np.clip(np.searchsorted(RANGE_BINS, r, side="right") - 1, 0, len(RANGE_NAMES) - 1)


def evaluate_frames(frames: list[FrameTruth], links: list[tuple[int, int, int]]) -> dict:
    """Metrics over frames (in order, consecutive) and links (frame index i, track id, i + 1 implied).

    links: (frame position i in `frames`, track id) pairs meaning the track links frame i to i + 1.
    """
    acc = _Acc()
    segs = [_segments(f) for f in frames]
    for s in segs:
        acc.seg_points.append(s["total"])
        acc.seg_dominant.append(s["dom_cnt"])
        acc.seg_class.append(s["dom"] >> 16)
        acc.seg_range.append(s["range"])
        _, per_obj = np.unique(s["dom"], return_counts=True)
        acc.overseg.append(per_obj)
    link_by_frame: dict[int, list[int]] = {}
    for i, tid in links:
        link_by_frame.setdefault(i, []).append(tid)
    for i in range(len(frames) - 1):
        a, b = segs[i], segs[i + 1]
        tids = np.asarray(link_by_frame.get(i, []), dtype=np.int64)
        tids = tids[np.isin(tids, a["ids"]) & np.isin(tids, b["ids"])]
        pa = np.searchsorted(a["ids"], tids)
        pb = np.searchsorted(b["ids"], tids)
        acc.link_ok.append(a["dom"][pa] == b["dom"][pb])
        acc.link_class.append(a["dom"][pa] >> 16)
        acc.link_range.append(a["range"][pa])
        # recall over instance presences with enough points in both frames
        fa, fb = frames[i], frames[i + 1]
        ka, ca = np.unique(fa.inst_key, return_counts=True)
        kb, cb = np.unique(fb.inst_key, return_counts=True)
        cls_a = ka >> 16
        objs = ka[(ca >= MIN_PRESENCE_POINTS) & (cls_a != GROUND) & (cls_a != UNLABELLED)]
        objs = objs[(objs & 0xFFFF) > 0]
        objs = np.intersect1d(objs, kb[cb >= MIN_PRESENCE_POINTS])
        acc.rec_hit.append(np.isin(objs, _linked_objects(a, b, tids)))
        acc.rec_class.append(objs >> 16)
        # presence range: mean range of the object's points in frame i
        m = np.isin(fa.inst_key, objs)
        key_pos = np.searchsorted(objs, fa.inst_key[m])
        rsum = np.bincount(key_pos, weights=np.linalg.norm(fa.points[m], axis=1), minlength=len(objs))
        rcnt = np.bincount(key_pos, minlength=len(objs))
        acc.rec_range.append(rsum / np.maximum(rcnt, 1))
    return _summarise(acc)


def thing_cover(frames: list[FrameTruth]) -> tuple[float | None, int]:
    """(mean share of a thing instance's points in its largest segment, instances): every person,
    car or cyclist instance with >= MIN_PRESENCE_POINTS points in a frame counts once per frame."""
    shares = []
    for ft in frames:
        thing = np.isin(ft.inst_key >> 16, THINGS) & ((ft.inst_key & 0xFFFF) > 0)
        keys, counts = np.unique(ft.inst_key[thing], return_counts=True)
        for key, n in zip(keys, counts, strict=True):
            if n >= MIN_PRESENCE_POINTS:
                seg = ft.track[ft.inst_key == key]
                shares.append(np.unique(seg[seg > 0], return_counts=True)[1].max(initial=0) / n)
    return (float(np.mean(shares)) if shares else None), len(shares)


def quality_summary(frames: list[FrameTruth], links: list[tuple[int, int]]) -> dict:
    """The headline numbers of the module docstring."""
    objects = []
    for ft in frames:
        cls = ft.key >> 16
        drop = (cls == GROUND) | (cls == UNLABELLED)
        objects.append(FrameTruth(np.where(drop, 0, ft.track).astype(ft.track.dtype), ft.key, ft.inst_key, ft.points))
    res = evaluate_frames(objects, links)
    cover, instances = thing_cover(frames)
    hits = [res["per_class"][name] for name in THING_NAMES if name in res["per_class"]]
    presences = sum(b["presences"] for b in hits)
    recalled = sum(b["presences"] * (b["association_recall"] or 0.0) for b in hits)
    return {
        "purity": res["overall"]["purity"],
        "thing_cover": cover,
        "thing_instances": instances,
        "link_precision": res["overall"]["association_precision"],
        "thing_link_recall": recalled / presences if presences else None,
        "link_recall": res["overall"]["association_recall"],
        "segments": res["overall"]["segments"],
    }


def track_objects(frames: list[FrameTruth]) -> tuple[np.ndarray, np.ndarray]:
    """(track ids (T,) int64 sorted, dominant instance key (T,) int64 of each): the instance key
    holding most of the track's points over all its frames."""
    tids, keys = [], []
    for ft in frames:
        m = ft.track > 0
        tids.append(ft.track[m].astype(np.int64))
        keys.append(ft.inst_key[m] & 0xFFFFFF)
    tid, key = _cat(tids, np.int64), _cat(keys, np.int64)
    if len(tid) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    pair, cnt = np.unique((tid << 24) | key, return_counts=True)
    t = pair >> 24
    order = np.lexsort((-cnt, t))
    pair, t = pair[order], t[order]
    first = np.ones(len(t), bool)
    first[1:] = t[1:] != t[:-1]
    return t[first], pair[first] & 0xFFFFFF


def evaluate_stitches(frames: list[FrameTruth], stitches: np.ndarray) -> dict:
    """How often a stitch (S, 2) track ids joins tracks whose dominant object is one instance
    (`same_object`) or one class (`same_class`); None where there are no stitches."""
    ids, obj = track_objects(frames)
    st = np.asarray(stitches, np.int64).reshape(-1, 2)
    st = st[np.isin(st, ids).all(axis=1)]
    if len(st) == 0:
        return {"stitches": 0, "same_object": None, "same_class": None}
    a, b = obj[np.searchsorted(ids, st[:, 0])], obj[np.searchsorted(ids, st[:, 1])]
    return {"stitches": int(len(st)), "same_object": float(np.mean(a == b)),
            "same_class": float(np.mean((a >> 16) == (b >> 16)))}


def _cat(xs: list[np.ndarray], dtype=np.float64) -> np.ndarray:
    return np.concatenate(xs).astype(dtype) if xs else np.zeros(0, dtype)


def _block(pts, dom, ok, hits, overseg) -> dict:
    out = {
        "segments": int(len(pts)),
        "purity": float(dom.sum() / pts.sum()) if pts.sum() else None,
        "pure_fraction": float(np.mean(dom / np.maximum(pts, 1) >= 0.95)) if len(pts) else None,
        "links": int(len(ok)),
        "association_precision": float(ok.mean()) if len(ok) else None,
        "presences": int(len(hits)),
        "association_recall": float(hits.mean()) if len(hits) else None,
    }
    if overseg is not None:
        out["over_segmentation"] = float(overseg.mean()) if len(overseg) else None
    return out


def _summarise(acc: _Acc) -> dict:
    pts, dom = _cat(acc.seg_points), _cat(acc.seg_dominant)
    scls, srng = _cat(acc.seg_class, np.int64), _range_bin(_cat(acc.seg_range))
    ok, lcls, lrng = _cat(acc.link_ok, bool), _cat(acc.link_class, np.int64), _range_bin(_cat(acc.link_range))
    hit, rcls, rrng = _cat(acc.rec_hit, bool), _cat(acc.rec_class, np.int64), _range_bin(_cat(acc.rec_range))
    result = {"overall": _block(pts, dom, ok, hit, _cat(acc.overseg)), "per_class": {}, "per_range": {}}
    for name in POINT_CLASSES:
        c = CLASS_INDEX[name]
        s, link, r = scls == c, lcls == c, rcls == c
        if s.any() or r.any():
            result["per_class"][name] = _block(pts[s], dom[s], ok[link], hit[r], None)
    for b, name in enumerate(RANGE_NAMES):
        s, link, r = srng == b, lrng == b, rrng == b
        result["per_range"][name] = _block(pts[s], dom[s], ok[link], hit[r], None)
    return result


def format_table(result: dict) -> str:
    """A readable text table of an evaluation result."""

    def f(v: float | None, pct: bool = True) -> str:
        if v is None:
            return "   -  "
        return f"{100 * v:6.1f}" if pct else f"{v:6.2f}"

    head = f"{'':<12}{'segments':>9}{'purity':>8}{'>=0.95':>8}{'links':>8}{'prec':>8}{'pres.':>8}{'recall':>8}"
    lines = [head]

    def row(name: str, b: dict) -> str:
        return (
            f"{name:<12}{b['segments']:>9}{f(b['purity']):>8}{f(b['pure_fraction']):>8}{b['links']:>8}"
            f"{f(b['association_precision']):>8}{b['presences']:>8}{f(b['association_recall']):>8}"
        )

    lines.append(row("overall", result["overall"]))
    sm = result.get("summary")
    if sm:
        lines.append(f"objects (ground and unlabelled points left out): purity {f(sm['purity']).strip()} %, "
                     f"thing cover {f(sm['thing_cover']).strip()} % ({sm['thing_instances']} instances), "
                     f"link precision {f(sm['link_precision']).strip()} %, "
                     f"thing link recall {f(sm['thing_link_recall']).strip()} %")
    lines.append(f"over-segmentation (segments per object): {f(result['overall'].get('over_segmentation'), False)}")
    st = result.get("stitches")
    if st:
        lines.append(f"stitches: {st['stitches']}, joining one object {f(st['same_object']).strip()} %, "
                     f"one class {f(st['same_class']).strip()} %")
    lines.append("-- per class")
    lines += [row(k, v) for k, v in result["per_class"].items()]
    lines.append("-- per range (m)")
    lines += [row(k, v) for k, v in result["per_range"].items()]
    return "\n".join(lines)
