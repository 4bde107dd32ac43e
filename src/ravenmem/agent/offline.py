"""The offline reasoner: answers from the embedder alone, made smarter by rules instead of a model.

1. Query rewriting: the thing asked about is cut out of the question ("Where did I leave the red
   backpack?" -> "red backpack"), paraphrased in the caption style embedders are trained on,
   reduced to its head noun, mapped through a few synonyms, and needs are turned into objects
   ("where can I sit" -> chair, sofa, bench). Paraphrases are averaged, alternatives maxed.
2. Text and OCR channels are fused: a memory whose OCR text contains the question's words
   gets a bonus (plus the memory's own OCR retrieval when it has OCR).
3. Temporal support: a real sighting persists over neighbouring memories while embedder noise
   is an isolated spike, so each hit's score is capped by the mean of the best scores in its
   time window.
4. "Found" needs that support above a threshold calibrated on this memory: the same pipeline
   run on decoy concepts (animals, vehicles, ...) gives the scores of things that are not
   there. Below it the answer is an honest "not found", never the least bad memory.
5. Temporal words: good hits in time order are split into episodes; "last" / "first" pick the
   latest / earliest sighting in every question type ("where did I last see", "when was the
   last time", "did I see ... recently"), "how long" sums the episodes.
6. Spatial consensus: good hits are clustered in the plane and the cluster with the most summed
   evidence wins over a single high-scoring outlier; its best memory gives the pose.
"""

from __future__ import annotations

import contextlib
import difflib
import hashlib
import json
import re
import threading
import time
import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..embed.ocr import OCR_WEIGHT, STOPWORDS
from ..errors import InputError
from ..memory.folder import OFFLINE_CALIBRATION
from ..memory.protocol import MemoryLike
from ..timeparse import fmt_time
from ..types import Hit, MemoryRecord
from .questions import Order, classify_question, fmt_duration, subject_phrase, temporal_order
from .schema import Answer, Cost, Evidence, PlaceChange

if TYPE_CHECKING:
    from ..memory.places import Place, Whereabouts

AFFORDANCES: dict[str, list[str]] = {
    r"\bsit\b|\bseat\b|\bsitting\b": ["chair", "sofa", "bench", "stool"],
    r"\bsleep\b|\blie down\b|\bnap\b": ["bed", "sofa"],
    r"\bdrink\b|\bthirsty\b": ["water bottle", "cup", "water fountain", "tap"],
    r"\beat\b|\bhungry\b|\bfood\b|\bsnack\b": ["dining table", "refrigerator", "plate of food"],
    r"\bwash\b|\bclean my hands\b": ["sink", "washbasin", "tap"],
    r"\bcook\b|\bheat\b": ["stove", "microwave oven"],
    r"\btype\b|\bwork\b|\bemail\b": ["desk", "computer keyboard", "computer monitor", "laptop"],
    r"\bcharge\b|\bplug\b|\bpower\b": ["power outlet", "charger cable"],
    r"\bthrow\b|\btrash\b|\brubbish\b|\bgarbage\b": ["trash can", "garbage bin"],
    r"\bprint\b": ["printer"],
    r"\bread\b": ["book", "bookshelf"],
    r"\bexit\b|\bleave the building\b|\bget out\b": ["door", "exit sign"],
    r"\bupstairs\b|\bdownstairs\b|\bgo up\b|\bgo down\b": ["stairs", "elevator"],
    r"\bcall\b": ["telephone", "cellular telephone"],
    r"\bcoffee\b": ["coffee mug", "coffee maker"],
    r"\bwrite\b|\bnote\b": ["pen", "whiteboard", "notebook"],
    r"\bplay\b|\bgame\b": ["game controller", "joystick"],
}
SYNONYMS: dict[str, str] = {
    "tv": "television",
    "couch": "sofa",
    "fridge": "refrigerator",
    "bin": "trash can",
    "mug": "coffee mug",
    "monitor": "computer monitor",
    "screen": "computer screen",
    "keyboard": "computer keyboard",
    "mouse": "computer mouse",
    "plant": "potted plant",
    "laptop": "laptop computer",
    "phone": "telephone",
    "cellphone": "cellular telephone",
    "gamepad": "game controller",
    "controller": "game controller",
    "bottle": "water bottle",
    # ImageNet has no person class: the plural reaches the bank's classes that show people
    # (ballplayer, groom, scuba diver, clothes) best (benchmarks/bench_person.py, docs/embedders.md)
    "person": "people",
    "someone": "people",
    "somebody": "people",
    "man": "people",
    "woman": "people",
    "human": "people",
}
# Things a robot's memory rarely holds all at once; their scores calibrate "not found".
DECOYS = (
    "shark",
    "elephant",
    "zebra",
    "giraffe",
    "jellyfish",
    "goldfish",
    "flamingo",
    "snail",
    "tiger",
    "horse",
    "cow",
    "spider",
    "butterfly",
    "eagle",
    "penguin",
    "volcano",
    "sailboat",
    "tractor",
    "airliner",
    "fire truck",
    "lighthouse",
    "bridge",
    "beach",
    "mountain",
    "train",
    "banana",
    "pineapple",
    "pizza",
    "bathtub",
    "umbrella",
    "guitar",
    "violin",
    "toilet",
    "washing machine",
    "bed",
    "vase",
    "wine bottle",
    "candle",
    "basketball",
    "tennis racket",
)
_DEICTIC = re.compile(
    r"^(this|that|it|these|those|this thing|this object|this place|here|there)$", re.IGNORECASE
)
# questions about the present: answered from the latest sightings and the revisits (ravenmem.memory.changes)
_NOW = re.compile(
    r"\b(now|currently|current|still|any ?more|at the moment|at present|these days|nowadays)\b", re.IGNORECASE
)
_PRESENT = re.compile(r"^\s*where(?:\s+(?:is|are)\b|'s\b)", re.IGNORECASE)
_START = re.compile(r"\b(?:at|in) the (?:start|beginning)\b|\bat first\b|\bto begin with\b", re.IGNORECASE)


@dataclass
class OfflineReasonerConfig:
    """Defaults were chosen on the TUM fr1_rpy question set of benchmarks/bench_reasoner.py."""

    pool: int = 200  # memories scored per rewritten query
    support_n: int = 3  # a hit's support = mean of the best n scores in its time window
    window_s: float | None = None  # half-width of that window; None = max(10 x keyframe spacing, 1 s)
    decoy_quantile: float = 0.9  # "found" threshold = this quantile of the decoys' support ...
    min_score: float | None = None  # ... or this fixed score when given (skips the decoys)
    rel_margin: float = 0.5  # good hits: support >= best - rel_margin * (best - threshold) ...
    temporal_margin: float = 0.75  # ... and this looser margin for first / last / how long
    cluster_radius: float = 1.0  # metres: good hits this close vote for the same place (at least
    # 1.5 x the memory's keyframe step, `_vote_radius`)
    max_good: int = 200  # at most this many good hits (best first) take part in votes and episodes


@dataclass
class Cand:
    rec: MemoryRecord
    score: float
    support: float = 0.0
    ocr: float = 0.0
    group: int = 0  # which rewritten query (or the image, last) gave it its score


def rewrite(question: str, subject: str) -> list[list[str]]:
    """Groups of queries: each group is paraphrases of one alternative (averaged), groups are maxed."""
    groups: list[list[str]] = []
    low = question.lower()
    if subject and not _DEICTIC.match(subject):
        groups.append(_paraphrases(subject))
        words = [w for w in re.findall(r"[a-z0-9]+", subject.lower()) if w not in STOPWORDS]
        head = words[-1] if words else ""
        if len(words) > 1 and head:
            groups.append(_paraphrases(head))
        for key in dict.fromkeys((subject.lower(), head)):
            if key in SYNONYMS:
                groups.append(_paraphrases(SYNONYMS[key]))
    for pattern, objects in AFFORDANCES.items():
        if re.search(pattern, low):
            groups += [_paraphrases(o) for o in objects]
    out, seen = [], set()
    for g in groups:
        if g[0] not in seen:
            seen.add(g[0])
            out.append(g)
    return out


def _paraphrases(phrase: str) -> list[str]:
    if phrase.lower().startswith(("a ", "an ", "the ")):
        return [phrase, f"a photo of {phrase}."]
    art = "an" if phrase[:1].lower() in "aeiou" else "a"
    return [phrase, f"a photo of {art} {phrase}."]


def ocr_overlap(words: Sequence[str], text: str) -> float:
    """Fraction of the words found (fuzzily) among the OCR tokens."""
    if not words or not text:
        return 0.0
    tokens = re.findall(r"[a-z0-9]+", text.lower())
    if not tokens:
        return 0.0
    hit = sum(1 for w in words if w in tokens or difflib.get_close_matches(w, tokens, n=1, cutoff=0.75))
    return hit / len(words)


# the decoys' text vectors per embedder object: they depend on the embedder alone, not on the
# memory, so a process embeds them once (a live memory recalibrates as it grows: searches only)
_DECOY_VECTORS: weakref.WeakKeyDictionary[Any, tuple[tuple[str, ...], np.ndarray]] = (
    weakref.WeakKeyDictionary()
)
_DECOY_LOCK = threading.Lock()


def decoy_vectors(embedder: Any, texts: list[str]) -> np.ndarray:
    """`embedder.embed_texts(texts)` (the decoys' paraphrases, one batch as ever), kept for the
    embedder's life; an embedder that cannot be weakly referenced is asked every time."""
    key = tuple(texts)
    with _DECOY_LOCK:
        try:
            kept = _DECOY_VECTORS.get(embedder)
        except TypeError:
            kept = None
        if kept is not None and kept[0] == key:
            return kept[1]
        vecs = np.asarray(embedder.embed_texts(texts))
        with contextlib.suppress(TypeError):
            _DECOY_VECTORS[embedder] = (key, vecs)
        return vecs


class OfflineReasoner:
    """Answers position / time / duration / binary / text questions without any model."""

    name = "offline"

    def __init__(
        self, memory: MemoryLike, top_k: int = 5, config: OfflineReasonerConfig | None = None
    ) -> None:
        self.memory = memory
        self.top_k = top_k
        self.s = config or OfflineReasonerConfig()
        self._decoy_support: dict[str, float] | None = None

    # ------------------------------------------------------------------ scoring
    def _search_many(self, texts: list[str], k: int) -> list[list[tuple[MemoryRecord, float]]]:
        """(record, cosine) lists per text, all texts embedded in one batch. OCR is fused
        separately (`_add_ocr`), so the image channel alone is asked for here. Not diverse: the
        votes below need every hit, near-duplicates of one moment included."""
        groups = self.memory.search_texts(texts, k=k, ocr=False, diverse=False)
        return [[(h.memory, float(h.score or 0.0)) for h in hits] for hits in groups]

    def _fuse(self, groups: list[list[str]], k: int, image: np.ndarray | None = None) -> dict[int, Cand]:
        """Per memory: max over groups of the mean over paraphrases (a missing one counts its floor)."""
        flat = [q for g in groups for q in g]
        results = iter(self._search_many(flat, k)) if flat else iter([])
        tables = [[{r.id: (r, sc) for r, sc in next(results)} for _ in g] for g in groups]
        if image is not None:
            hits = self.memory.search_image(image, k=k, diverse=False)
            tables.append([{h.memory.id: (h.memory, float(h.score or 0.0)) for h in hits}])
        cands: dict[int, Cand] = {}
        for gi, paraphrases in enumerate(tables):
            for mid, (rec, score) in _group_scores(paraphrases).items():
                c = cands.get(mid)
                if c is None:
                    cands[mid] = Cand(rec, score, group=gi)
                elif score > c.score:
                    c.score, c.group = score, gi
        return cands

    def _add_ocr(self, cands: dict[int, Cand], subject: str, k: int) -> None:
        words = [w for w in re.findall(r"[a-z0-9]+", subject.lower()) if w not in STOPWORDS and len(w) >= 2]
        if not words:
            return
        if self.memory.ocr_enabled:  # OCR-only matches the vectors missed
            for h in self.memory.search_text(" ".join(words), k=min(k, 20), diverse=False):
                if h.ocr_match and h.memory.id not in cands:
                    cands[h.memory.id] = Cand(h.memory, float(h.score or 0.0) - OCR_WEIGHT)
        for c in cands.values():
            c.ocr = ocr_overlap(words, c.rec.ocr_text)
            c.score += OCR_WEIGHT * c.ocr

    def _window(self) -> float:
        if self.s.window_s is not None:
            return self.s.window_s
        t0, t1 = self.memory.time_span()
        spacing = (t1 - t0) / max(1, self.memory.count() - 1)
        return max(10.0 * spacing, 1.0)

    def _support(self, cands: dict[int, Cand]) -> None:
        """Each hit's support: its score, capped by the mean of the best n scores in its time window
        (an isolated spike is pulled down; a weak hit never borrows its neighbours' strength)."""
        if not cands:
            return
        w, n = self._window(), self.s.support_n
        cs = sorted(cands.values(), key=lambda c: c.rec.t)
        ts = np.array([c.rec.t for c in cs])
        sc = np.array([c.score for c in cs])
        lo, hi = np.searchsorted(ts, ts - w, "left"), np.searchsorted(ts, ts + w, "right")
        for i, c in enumerate(cs):
            c.support = min(c.score, float(np.sort(sc[lo[i] : hi[i]])[::-1][:n].mean()))

    def threshold(self, subject: str = "") -> float:
        """The "found" threshold: fixed, or calibrated once per memory on the decoys (a decoy that
        is the very thing asked about is left out)."""
        if self.s.min_score is not None:
            return self.s.min_score
        if self._decoy_support is None:
            self._decoy_support = self._load_calibration() or self._calibrate()
        low = subject.lower()
        vals = [v for name, v in self._decoy_support.items() if not re.search(rf"\b{re.escape(name)}\b", low)]
        return float(np.quantile(vals, self.s.decoy_quantile))

    def adopt_calibration(self, other: OfflineReasoner) -> bool:
        """Take `other`'s decoy calibration when it was made on the same memory with the same
        settings (a served memory's one `support.Judge` lends its own to each question, so `ask`
        and the search verdicts decline by one threshold and a question does not recalibrate);
        False, keeping its own, otherwise."""
        if other.memory is not self.memory or other.s != self.s or other._decoy_support is None:
            return False
        self._decoy_support = other._decoy_support
        return True

    def _calibration_key(self) -> str:
        emb = self.memory.embedder.name
        t0, t1 = self.memory.time_span()
        parts = [
            emb,
            self.memory.count(),
            round(t0, 3),
            round(t1, 3),
            self.s.pool,
            self.s.support_n,
            self.s.window_s,
        ]
        return hashlib.sha1(json.dumps([parts, DECOYS], default=str).encode()).hexdigest()[:16]

    def _load_calibration(self) -> dict[str, float] | None:
        """Decoy scores cached in the memory folder, valid while the memory and settings are unchanged."""
        try:
            data = json.loads((Path(self.memory.path) / OFFLINE_CALIBRATION).read_text(encoding="utf-8"))
            if data.get("key") == self._calibration_key():
                return {str(k): float(v) for k, v in data["decoys"].items()}
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            pass
        return None

    def _calibrate(self) -> dict[str, float]:
        pool = max(1, min(self.memory.count(), self.s.pool))
        groups = [_paraphrases(d) for d in DECOYS]
        flat = [q for g in groups for q in g]
        search_vectors = getattr(self.memory, "search_vectors", None)
        if search_vectors is not None:  # the decoys embedded once per embedder (`decoy_vectors`)
            hits = search_vectors(decoy_vectors(self.memory.embedder, flat), k=pool, diverse=False)
            results = iter([[(h.memory, float(h.score or 0.0)) for h in g] for g in hits])
        else:
            results = iter(self._search_many(flat, pool))
        out: dict[str, float] = {}
        for name, g in zip(DECOYS, groups, strict=True):
            table = [{r.id: (r, sc) for r, sc in next(results)} for _ in g]
            cands = {mid: Cand(rec, sc) for mid, (rec, sc) in _group_scores(table).items()}
            self._support(cands)
            out[name] = max((c.support for c in cands.values()), default=0.0)
        if not getattr(self.memory, "is_writer", False):
            return out  # a reader (ask, search) never writes in the memory folder: kept in RAM
        try:
            from ..fsio import atomic_write

            text = json.dumps({"key": self._calibration_key(), "decoys": out}, indent=1)
            atomic_write(Path(self.memory.path) / OFFLINE_CALIBRATION, text)
        except OSError:  # a read-only memory still answers; it just calibrates again next time
            pass
        return out

    def _scored(
        self, groups: list[list[str]], subject: str, image: np.ndarray | None
    ) -> tuple[dict[int, Cand], float]:
        """The candidates with their support, and the "found" threshold (steps 1-4 above)."""
        pool = max(1, min(self.memory.count(), self.s.pool))
        cands = self._fuse(groups, pool, image)
        self._add_ocr(cands, subject, pool)
        self._support(cands)
        return cands, self.threshold(subject)

    def support(self, query: str) -> tuple[dict[int, float], float]:
        """Each memory's support for the thing `query` names, scored exactly as `ask` scores the
        thing asked about, and the threshold under which `ask` declines: the verdict search
        results carry (ravenmem.agent.support). Memories outside the scored pool are left out."""
        subject = subject_phrase(query) or query
        groups = rewrite(query, subject)
        if not groups:
            raise InputError(f"cannot tell what to look for in {query!r}")
        cands, thr = self._scored(groups, subject, None)
        return {mid: c.support for mid, c in cands.items()}, thr

    # ------------------------------------------------------------------ answering
    def ask(self, question: str, image: np.ndarray | None = None) -> Answer:
        if not question or not question.strip():
            raise InputError("empty question")
        t_start = time.perf_counter()
        mem, s = self.memory, self.s
        qtype, order = classify_question(question), temporal_order(question)
        subject = subject_phrase(question)
        now = bool(_NOW.search(question)) and not _START.search(question)
        if _START.search(question):
            order, subject = "first", _cut(subject, _START)
        elif now:  # "is the mug still in the first room?" is about now, not about a first sighting
            order, subject = "best", _cut(subject, _NOW)
        groups = rewrite(question, subject)
        if not groups and image is None:
            raise InputError(f"cannot tell what to look for in {question!r}")
        n = mem.count()
        cands, thr = self._scored(groups, subject, image)
        ranked = sorted(cands.values(), key=lambda c: -c.support)
        best = ranked[0] if ranked else None
        found = best is not None and best.support > thr
        ans = Answer(
            question=question, method=self.name, question_type=qtype, found=found, embedder=mem.embedder.name
        )
        notes = [f"queries: {[g[0] for g in groups] + (['<image>'] if image is not None else [])}"]
        if best is not None:
            notes.append(f"best support {best.support:.3f} vs threshold {thr:.3f}")
        if found and best is not None:
            # "first"/"last"/"how long" need every sighting; "where"/"is there" only the strongest
            temporal = order != "best" or qtype == "duration"
            margin = s.temporal_margin if temporal else s.rel_margin
            cut = max(thr, best.support - margin * (best.support - thr))
            good = [c for c in ranked if c.support >= cut and c.score >= thr][: s.max_good] or [best]
            radius = self._vote_radius(cands)
            self._answer(ans, qtype, order, subject or "it", good, (cut, radius), notes)
            present = qtype == "position" and order == "best" and bool(_PRESENT.search(question))
            if now or present:
                w = self._whereabouts(self._vector(groups, best.group, image), thr, notes)
                stale = _stale_place(w, ans.evidence[0].id if ans.evidence else None)
                if w is not None and present and not now and stale is not None:
                    notes.append(
                        f"the best match m{stale.last.id} is at a place the robot later saw without it "
                        f"({stale.verdict}): answered from the latest sightings"
                    )
                if w is not None and (now or stale is not None):
                    self._answer_now(ans, qtype, subject or "it", w, notes)
        else:
            self._not_found(ans, subject or "it", qtype, ranked, thr)
        ans.reasoning = "; ".join(notes)
        ans.cost = Cost(
            memories_shown=len(cands),
            memories_total=n,
            alpha=len(cands) / max(1, n),
            wall_s=round(time.perf_counter() - t_start, 4),
        )
        return ans

    def _episodes(self, good: list[Cand]) -> list[list[Cand]]:
        """Good hits in time order, split where sightings are further apart than the window."""
        gap = self._window()
        chrono = sorted(good, key=lambda c: c.rec.t)
        eps = [[chrono[0]]]
        for c in chrono[1:]:
            if c.rec.t - eps[-1][-1].rec.t > gap:
                eps.append([c])
            else:
                eps[-1].append(c)
        return eps

    def _vote_radius(self, cands: dict[int, Cand]) -> float:
        """How close two good hits must be to vote for one place: `cluster_radius`, widened to
        1.5 x the median step between consecutive memories (ids i and i + 1 among the
        candidates) taken while moving. Keyframes come every so many metres of travel but every
        few degrees of turning, so with a radius under the step an approach to a thing is split
        into single memories while a turn in place (a doorway) stacks them: the vote would count
        the keyframe rule's turns, not the evidence."""
        poses = {i: (c.rec.pose.x, c.rec.pose.y) for i, c in cands.items()}
        steps = [
            float(np.hypot(poses[i][0] - poses[i + 1][0], poses[i][1] - poses[i + 1][1]))
            for i in poses
            if i + 1 in poses
        ]
        moving = [d for d in steps if d > 0.1]
        if len(moving) < 5:
            return self.s.cluster_radius
        return max(self.s.cluster_radius, 1.5 * float(np.median(moving)))

    def _consensus(self, good: list[Cand], bar: float, radius: float) -> list[Cand]:
        """The winning place: clusters of nearby good hits vote with their summed evidence, each
        hit's evidence being its support above `bar`, the support a hit needs to be good. Measured
        from the "found" threshold instead, every good hit would weigh at least (1 - rel_margin)
        of the best one, so any two marginal hits taken from one spot (a doorway the robot turned
        in, say) would outvote the strongest match: the count of memories, not their strength,
        would choose the place."""
        clusters: list[list[Cand]] = []
        r2 = radius**2
        for c in sorted(good, key=lambda c: -c.support):
            p = c.rec.pose
            home = next(
                (
                    cl
                    for cl in clusters
                    if (cl[0].rec.pose.x - p.x) ** 2 + (cl[0].rec.pose.y - p.y) ** 2 <= r2
                ),
                None,
            )
            if home is None:
                clusters.append([c])
            else:
                home.append(c)
        return max(clusters, key=lambda cl: sum(max(c.support - bar, 0.0) + 1e-6 for c in cl))

    def _answer(
        self,
        ans: Answer,
        qtype: str,
        order: Order,
        subject: str,
        good: list[Cand],
        vote: tuple[float, float],
        notes: list[str],
    ) -> None:
        """`vote`: the good-hit bar and the radius of the spatial vote (`_consensus`)."""
        eps = self._episodes(good)
        scope = {"last": eps[-1], "first": eps[0]}.get(order) or good
        notes.append(
            f"{len(good)} good hits in {len(eps)} episode(s)"
            + (f"; using the {order}" if order != "best" else "")
        )
        by_support = sorted(scope, key=lambda c: -c.support)
        if order != "best" and qtype != "duration":
            # "last" is the latest sighting (and "first" the earliest) whatever the question asks
            # for: where, when or whether. The strongest hit of that episode would be an older
            # one; the latest hit of all could be a lone glimpse elsewhere, so the place is the
            # episode's spatial vote and the answer that place's latest (earliest) sighting
            place = self._consensus(scope, *vote)
            chrono = sorted(place, key=lambda c: (c.rec.t, c.rec.id))
            chosen = chrono[-1] if order == "last" else chrono[0]
            notes.append(
                f"spatial vote: {len(place)} of {len(scope)} hits agree; the "
                f"{'latest' if order == 'last' else 'earliest'} good hit there is m{chosen.rec.id}"
            )
            evidence = [chosen] + [c for c in by_support if c is not chosen]
        elif qtype == "position":
            place = self._consensus(scope, *vote)
            notes.append(f"spatial vote: {len(place)} of {len(scope)} hits agree")
            chosen = max(place, key=lambda c: (c.support, c.score))  # a tie: the stronger own match
            evidence = [chosen] + [c for c in sorted(place, key=lambda c: -c.support) if c is not chosen]
        else:
            chosen = by_support[0]
            evidence = [chosen] + [c for c in sorted(good, key=lambda c: -c.support) if c is not chosen]
        p = chosen.rec.pose
        ans.position, ans.yaw = [p.x, p.y, p.z], p.yaw
        ans.position_source = ans.yaw_source = "evidence"
        ans.time = chosen.rec.t
        ans.evidence = [_ev(c) for c in evidence[: self.top_k]]
        where, when = f"at x={p.x:.2f}, y={p.y:.2f}, z={p.z:.2f}", fmt_time(chosen.rec.t)
        if qtype == "duration":
            t0, t1 = self.memory.time_span()
            spacing = (t1 - t0) / max(1, self.memory.count() - 1)
            ans.duration = sum(ep[-1].rec.t - ep[0].rec.t + spacing for ep in eps)
            ans.text = f"About {fmt_duration(ans.duration)}, in {len(eps)} sighting(s) of {subject}."
        elif qtype == "binary":
            ans.yes = True
            ans.text = f"Yes: {subject} was seen {where} at {when}."
        elif qtype == "time":
            label = {"last": "Last", "first": "First"}.get(order, "Best")
            ans.text = f"{label} sighting of {subject}: {when}, {where}."
        elif qtype == "text" and chosen.rec.ocr_text:
            ans.text = f"Text seen there: {chosen.rec.ocr_text!r} ({when}, {where})."
        else:
            seen = {"last": "last seen", "first": "first seen"}.get(order, "seen")
            ans.text = f"{subject[:1].upper() + subject[1:]}: {seen} {where} at {when}."
        if qtype == "text":
            notes.append("the offline reasoner cannot describe images; it reports where and when")

    def _vector(self, groups: list[list[str]], group: int, image: np.ndarray | None) -> np.ndarray:
        """The query that scored the best hit, as one vector: the mean of its paraphrases'
        embeddings (so its cosine is the mean the scores above used), or the image's."""
        emb = self.memory.embedder
        if group < len(groups):
            return np.asarray(emb.embed_texts(groups[group]), np.float32).mean(axis=0)
        assert image is not None
        return np.asarray(emb.embed_images([image])[0], np.float32)

    def _whereabouts(self, vector: np.ndarray, thr: float, notes: list[str]) -> Whereabouts | None:
        """The thing's places and verdicts (`ravenmem.memory.changes`), or None (with a note) when the
        memory cannot give them or no sighting stands out."""
        w = self.memory.last_seen(vector=vector, min_score=thr)
        if not w.places:
            notes.append("latest mode: no sighting stands out; answered from the best matches")
            return None
        return w

    def _answer_now(self, ans: Answer, qtype: str, subject: str, w: Whereabouts, notes: list[str]) -> None:
        """A question about the present ("now", "still", "currently"): the answer comes from the
        latest sightings and what later visits of their places showed (`ravenmem.memory.changes`)."""
        notes.append(f"latest mode: status {w.status} over {len(w.places)} place(s)")
        ans.changes = [
            PlaceChange.model_validate({**p.as_dict(), "query": subject, "status": w.status})
            for p in w.places
        ]
        name = subject[:1].upper() + subject[1:]
        moved = w.moved_from[:1]
        before = "".join(
            f" It was at x={p.last.pose.x:.2f}, y={p.last.pose.y:.2f} until {fmt_time(p.last_t)}; that place "
            f"was looked at again at {fmt_time(p.revisited or p.last_t)} without it."
            for p in moved
        )
        here = w.now
        if here is None:
            top = w.latest
            assert top is not None
            p = top.last.pose
            why = w.status_note or top.sentence()
            ans.found, ans.position, ans.yaw, ans.time = False, None, None, top.last_t
            ans.position_source = ans.yaw_source = "none"
            ans.evidence = [_ev_hit(h) for h in [top.last_hit, *top.revisits]][: self.top_k]
            ans.text = (
                f"I don't know where {subject} is now: last seen from x={p.x:.2f}, y={p.y:.2f} at "
                f"{fmt_time(top.last_t)}, and not seen since ({why})."
            )
            if qtype == "binary":
                ans.yes = False
                ans.text = "No: " + ans.text
            return
        p = here.last.pose
        ans.position, ans.yaw, ans.time = [p.x, p.y, p.z], p.yaw, here.last_t
        ans.position_source = ans.yaw_source = "evidence"
        ans.evidence = [_ev_hit(h) for h in here.newest(self.top_k)]
        where, when = f"x={p.x:.2f}, y={p.y:.2f}, z={p.z:.2f}", fmt_time(here.last_t)
        if qtype == "binary":
            ans.yes = not moved
            ans.text = (
                f"No: {subject} moved. Seen since at {where} (last at {when})." + before
                if moved
                else f"Yes: {subject} was last seen at {where} at {when} ({here.verdict})."
            )
        elif qtype == "time":
            ans.text = f"Last sighting of {subject}: {when}, {where} ({here.verdict})." + before
        else:
            ans.text = f"{name} is now at {where}: last seen there at {when} ({here.verdict})." + before

    def _not_found(self, ans: Answer, subject: str, qtype: str, ranked: list[Cand], thr: float) -> None:
        """Declined: say why (the best match's support under the threshold, and what that threshold
        is) and show the closest misses, so that a search that does list them is explained."""
        ans.text = f"I don't remember seeing {subject}."
        if ranked:
            best = ranked[0]
            p = best.rec.pose
            why = (
                f"the best match, m{best.rec.id} at x={p.x:.2f}, y={p.y:.2f} ({fmt_time(best.rec.t)}), "
                f"scores {best.score:.3f} ({best.support:.3f} with its neighbours in time), under this "
                f"memory's threshold {thr:.3f}"
            )
            if self.s.min_score is None:
                why += (
                    f" ({100 * self.s.decoy_quantile:.0f}% of {len(DECOYS)} things that are not there, "
                    "such as a shark or a tractor, score under it here: the embedder rates this match "
                    "no better than them)"
                )
            else:
                why += " (the fixed min_score)"
            ans.text = f"I don't remember seeing {subject}: {why}."
            ans.notes.append(f"declined: best support {best.support:.3f} under the threshold {thr:.3f}")
            # the closest misses, for the curious (a search lists them too); no pose is claimed
            ans.evidence = [_ev(c) for c in ranked[: self.top_k]]
        if qtype == "binary":
            ans.yes = False
            ans.text = "No: " + ans.text


def _stale_place(w: Whereabouts | None, memory_id: int | None) -> Place | None:
    """The place holding `memory_id` when the robot later saw it without the thing."""
    if w is None or memory_id is None:
        return None
    for p in w.places:
        if p.verdict in ("moved", "gone") and memory_id in p.found.ids.tolist():
            return p
    return None


def _cut(subject: str, words: re.Pattern[str]) -> str:
    """The subject before a time word ("red box now" -> "red box", "Is the green box still
    there" -> "green box"), when something is left."""
    m = words.search(subject)
    head = subject[: m.start()] if m else subject
    head = re.sub(r"^(?:is|are|was|were)\s+(?:there\s+)?", "", head.strip(), flags=re.IGNORECASE)
    head = re.sub(r"^(?:the|a|an|my|our|your|any|some)\s+", "", head, flags=re.IGNORECASE).strip(" ?.!,")
    return head or subject


def _ev_hit(h: Hit) -> Evidence:
    return Evidence.of(h.memory, h.score)


def _ev(c: Cand) -> Evidence:
    return Evidence.of(c.rec, c.score)


def _group_scores(
    paraphrases: list[dict[int, tuple[MemoryRecord, float]]],
) -> dict[int, tuple[MemoryRecord, float]]:
    """Mean score over paraphrases per memory; a memory one paraphrase missed gets that one's floor."""
    floors = [min((sc for _, sc in t.values()), default=0.0) for t in paraphrases]
    out = {}
    for mid in set().union(*paraphrases):
        rec = next(t[mid][0] for t in paraphrases if mid in t)
        total = sum(t[mid][1] if mid in t else f for t, f in zip(paraphrases, floors, strict=True))
        out[mid] = (rec, total / len(paraphrases))
    return out
