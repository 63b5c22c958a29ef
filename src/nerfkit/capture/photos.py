"""Scan a folder of photos: load each upright, detect tags, cache the results.

Every photo becomes a :class:`PhotoRecord`; unreadable files are recorded with the reason
instead of stopping the run. Photos where no tag is found get a second, more careful detection pass
(:func:`~.aruco.detect_careful`); its finds are kept only for tag ids that the first pass
found in other photos (or that the layout holds), since a permissive detector can read
false ids in textures: so it waits for the first pass over every photo, and is not run when
that found no tag and there is no layout. Detections are cached in a JSON file keyed by
file name, size and modification time (and the detection settings), so re-running on the
same folder only looks at new or changed photos.
"""

from __future__ import annotations

import json
import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import NerfkitError, fail, problem_of
from ..images import (
    common_frame,
    common_size,
    copies,
    copy_reason,
    exif_focal_35mm,
    held_as,
    list_images,
    load_image_uint8,
    orientation_tag,
    turns_into_frame,
)
from ..io.atomic import shown_names, write_json
from ..io.paths import refuse_special_file
from .aruco import (
    SEARCH_DICTIONARIES,
    Detection,
    DictionaryFind,
    DictionarySearch,
    Layout,
    detect,
    detect_careful,
    make_detector,
    marker_bits,
)

CACHE_VERSION = 5  # 5: HEIF photos record the orientation pillow-heif applied
# A cache entry's mark: the first pass found no tag in the photo and the careful second
# pass has not looked yet (it runs once some photo shows a tag; earlier entries have no mark).
SECOND_PASS_DUE = "second_pass_due"
# Photos spread through a folder that are looked at first: for the dictionary asked for
# before the scan of all (:func:`probe_sample`), for other dictionaries after it found none.
SAMPLE_PHOTOS = 5


@dataclass
class PhotoRecord:
    """One photo and what happened to it.

    Attributes:
        name: file name (the key tying every output back to the photo).
        path: full path.
        detection: tags found, or None when the photo could not be read.
        error: why the photo could not be read, or None.
        exif_f35: EXIF FocalLengthIn35mmFilm in mm, or None.
        orientation: the EXIF Orientation tag (1: stored upright, 6 and 8: held the other way).
        turns: clockwise quarter turns that brought the upright photo (and ``detection``)
            into the frame of the other photos or the camera (:func:`turn_into_frame`); 0 for most.
        used: whether the stage using it (calibration, posing) kept it.
        reason: why it was skipped (empty when used).
        error_px: reprojection error (RMS, pixels) in the stage that used it.
        info: free-form per-stage details (e.g. pose ambiguity).
    """

    name: str
    path: Path
    detection: Detection | None = None
    error: str | None = None
    exif_f35: float | None = None
    orientation: int = 1
    turns: int = 0
    used: bool = False
    reason: str = ""
    error_px: float | None = None
    info: dict = field(default_factory=dict)

    @property
    def detected(self) -> Detection:
        """``detection`` of a photo known to have been read (stages after detection
        only see those)."""
        assert self.detection is not None, f"{self.name} was not read"
        return self.detection

    @property
    def detected_size(self) -> tuple[int, int]:
        """``size`` of a photo known to have been read."""
        return self.detected.width, self.detected.height

    @property
    def size(self) -> tuple[int, int] | None:
        return None if self.detection is None else (self.detection.width, self.detection.height)

    def skip(self, reason: str) -> None:
        self.used, self.reason = False, reason

    def summary(self) -> dict:
        d = {
            "file": self.name,
            "used": self.used,
            "reason": self.reason or None,
            "error_px": None if self.error_px is None else round(float(self.error_px), 4),
        }
        if self.detection is not None:
            d["size"] = [self.detection.width, self.detection.height]
            d["tags"] = [int(i) for i in self.detection.ids]
            d["sharpness"] = round(self.detection.sharpness, 2)
        if self.exif_f35:
            d["exif_focal_35mm"] = self.exif_f35
        if self.turns:
            d["turned_deg"] = 90 * self.turns  # clockwise, from upright into the other photos' frame
        d.update(self.info)
        return d


def _file_key(path: Path) -> list:
    st = path.stat()
    return [st.st_size, st.st_mtime_ns]


def resized_since_scanned(cache_path: Path, paths: list[Path]) -> list[Path]:
    """The photos among ``paths`` whose size in bytes differs from what the detection cache at
    ``cache_path`` recorded when they were scanned (replaced or edited since); none without
    a readable cache."""
    try:
        photos = json.loads(refuse_special_file(cache_path).read_text()).get("photos")
    except (OSError, ValueError, AttributeError):
        return []
    if not isinstance(photos, dict):
        return []
    changed = []
    for p in paths:
        entry = photos.get(Path(p).name)
        key = entry.get("key") if isinstance(entry, dict) else None
        size = key[0] if isinstance(key, list) and key and isinstance(key[0], int) else None
        if size is not None and Path(p).is_file() and Path(p).stat().st_size != size:
            changed.append(Path(p))
    return changed


def _load_cache(cache_path: Path | None, settings: dict) -> tuple[dict, bool]:
    """The cached entries for these settings, and whether the file may be written: a file
    there that is not a detection cache (caches are written whole, so never half) is the
    user's, and is left as it is."""
    if cache_path is None or not cache_path.exists():
        return {}, cache_path is not None
    try:
        data = json.loads(refuse_special_file(cache_path).read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError):
        data = None
    if (
        not isinstance(data, dict)
        or not {"version", "settings"} <= set(data)
        or not isinstance(data.get("photos"), dict)
    ):
        print(
            f"note: {cache_path} is not a nerfkit detection cache; it is left as it is, and detections "
            "are not cached this time",
            file=sys.stderr,
        )
        return {}, False
    if data.get("version") != CACHE_VERSION or data.get("settings") != settings:
        return {}, True  # another version's or other settings' cache: replaced
    return data["photos"], True


def _detect_one(path: Path, detector, detect_side: int, bits: int, careful: bool = False) -> dict:
    """Load upright and detect; a JSON-ready cache entry (never raises for a bad photo). With
    ``careful``, a photo with no tag is marked for the second pass (:func:`_second_pass`)."""
    entry: dict = {"key": _file_key(path)}
    try:
        image = load_image_uint8(path)
    except NerfkitError as e:
        entry["error"] = problem_of(e)
        return entry
    except MemoryError:
        entry["error"] = "out of memory while decoding"
        return entry
    try:
        det = detect(image, detector, detect_side, bits)
        entry["detection"] = det.to_json()
    except Exception as e:  # noqa: BLE001 - one odd photo must not stop the run
        entry["error"] = f"tag detection failed ({type(e).__name__}: {str(e).strip().splitlines()[-1][:120]})"
        return entry
    if careful and not len(det.ids) and det.charuco_ids is None:
        entry[SECOND_PASS_DUE] = True
    entry["exif_f35"], entry["orientation"] = _exif_header(path)
    return entry


def _second_pass(path: Path, entry: dict, dictionary: str, detect_side: int, bits: int) -> dict:
    """``entry`` of a photo the first pass found no tag in, after the careful detector's
    look (:func:`~.aruco.detect_careful`); when that fails, the first pass's entry stands."""
    entry = {k: v for k, v in entry.items() if k != SECOND_PASS_DUE}
    try:
        second = detect_careful(load_image_uint8(path), dictionary, detect_side, bits)
    except Exception:  # noqa: BLE001 - one odd photo must not stop the run
        return entry
    if len(second.ids):
        entry["detection"], entry["second_pass"] = second.to_json(), True
    return entry


def _exif_header(path: Path) -> tuple[float | None, int]:
    """EXIF FocalLengthIn35mmFilm (or None) and Orientation (1 when absent) from one read
    of the header, without decoding the pixels again (the focal length falls back to
    :func:`nerfkit.images.exif_focal_35mm`, which does)."""
    try:
        from PIL import Image

        with Image.open(path) as img:
            exif = img.getexif()
            value = exif.get_ifd(0x8769).get(0xA405) or exif.get(0xA405)
            return (float(value) if value else None), orientation_tag(img)
    except Exception:  # noqa: BLE001 - EXIF is optional metadata
        return exif_focal_35mm(path), 1


def scan_photos(
    folder: str | Path,
    dictionary: str,
    layout: Layout | None = None,
    detect_side: int = 2000,
    cache_path: str | Path | None = None,
    jobs: int = 2,
    progress: bool = True,
    files: list[Path] | None = None,
) -> list[PhotoRecord]:
    """Detect tags in every photo of ``folder`` (sorted by name), reusing the cache; then,
    when some photo shows a tag (or ``layout`` is given), look again with the careful
    detector at the photos showing none.

    Unreadable photos come back skipped with the reason; :func:`require_tags` checks that
    some photo shows a tag. Raises NerfkitError when the folder holds no images, or when a
    sample of the photos shows tags of another dictionary only (:func:`probe_sample`).
    """
    files = list_images(folder) if files is None else files
    charuco = layout is not None and layout.charuco is not None
    settings = {
        "dictionary": dictionary,
        "detect_side": int(detect_side),
        "charuco": layout.to_json() if charuco and layout is not None else None,
    }
    cache_path = Path(cache_path) if cache_path else None
    cache, writable = _load_cache(cache_path, settings)
    if not writable:
        cache_path = None
    entries: dict[str, dict] = {}
    todo = []
    for f in files:
        c = cache.get(f.name)
        if c is not None and c.get("key") == _file_key(f):
            entries[f.name] = c
        else:
            todo.append(f)

    def save() -> None:
        if cache_path is not None:
            write_json(
                cache_path,
                {"version": CACHE_VERSION, "settings": settings, "photos": {k: entries[k] for k in sorted(entries)}},
            )

    if todo and not charuco and not any(e.get("detection", {}).get("ids") for e in entries.values()):
        probe_sample(todo, folder, dictionary, detect_side, progress)  # none cached shows a tag
    bits = marker_bits(dictionary)
    local = threading.local()  # one detector per thread: OpenCV detectors are not shared

    def first_pass(f: Path) -> dict:
        if not hasattr(local, "detector"):
            local.detector = make_detector(dictionary, layout if charuco else None)
        return _detect_one(f, local.detector, detect_side, bits, careful=not charuco)

    made = 0  # entries (re)made by this run

    def keep(f: Path, entry: dict) -> None:
        nonlocal made
        entries[f.name], made = entry, made + 1
        if made % 10 == 0:
            save()  # an interrupted run keeps what it did

    def second_pass(f: Path) -> dict:
        return _second_pass(f, entries[f.name], dictionary, detect_side, bits)

    try:
        _in_threads(todo, first_pass, keep, f"detecting tags ({len(files) - len(todo)} cached)", jobs, progress)
        known = _known_ids(entries, layout)
        due = [f for f in files if entries[f.name].get(SECOND_PASS_DUE)]
        if due and known:  # its finds are kept for known ids only: without any, it is not run
            _in_threads(due, second_pass, keep, f"second pass on {len(due)} photos without tags", jobs, progress)
    finally:
        if made:
            save()
    records = []
    copied = copies(files)
    for f in files:
        e = entries[f.name]
        rec = PhotoRecord(f.name, f)
        if f.name in copied:
            rec.skip(copy_reason(copied[f.name]))
        elif "error" in e:
            rec.error = e["error"]
            rec.skip(f"unreadable: {e['error']}")
        else:
            rec.detection = Detection.from_json(e["detection"])
            rec.exif_f35 = e.get("exif_f35")
            rec.orientation = int(e.get("orientation", 1))
            if e.get("second_pass"):
                _keep_known_ids(rec, known)
        records.append(rec)
    return records


def _in_threads(paths: list[Path], work, keep, desc: str, jobs: int, progress: bool) -> None:
    """``work(path)`` for each of ``paths`` in ``jobs`` threads behind a progress bar;
    ``keep(path, result)`` as each ends."""
    from tqdm import tqdm

    if not paths:
        return
    bar = tqdm(total=len(paths), desc=desc, unit="photo", disable=None if progress else True, leave=False)
    pool = ThreadPoolExecutor(max(1, jobs))
    try:
        futures = {pool.submit(work, p): p for p in paths}
        for fut in as_completed(futures):
            keep(futures[fut], fut.result())
            bar.update(1)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        bar.close()


def _known_ids(entries: dict[str, dict], layout: Layout | None) -> set[int]:
    """The tag ids the first pass found in any photo, and the layout's."""
    first = {
        i for e in entries.values() if "detection" in e and not e.get("second_pass") for i in e["detection"]["ids"]
    }
    return {int(i) for i in first} | set(layout.ids if layout is not None else [])


def _keep_known_ids(rec: PhotoRecord, known: set[int]) -> None:
    """Drop second-pass tags whose id no first pass saw; note what the second pass found."""
    det = rec.detection
    assert det is not None  # only called for a photo just read
    keep = np.array([int(i) in known for i in det.ids], np.bool_)
    dropped = sorted({int(i) for i in det.ids[~keep]})
    det.ids, det.corners = det.ids[keep], det.corners[keep]
    if len(det.ids):
        rec.info["detection"] = "second pass (careful detector)"
    if dropped:
        rec.info["second_pass_ignored_ids"] = dropped


def require_tags(
    records: list[PhotoRecord], folder: str | Path, dictionary: str, otherwise: str = "", progress: bool = True
) -> None:
    """Raise a helpful NerfkitError when no photo shows any tag of ``dictionary``: naming the
    dictionary that finds them (:func:`another_dictionary`), else what to check (``otherwise``:
    a way on without tags, added to the advice)."""
    readable = [r for r in records if r.detection is not None]
    if not readable:
        reasons = "; ".join(f"{r.name}: {r.error}" for r in records[:3])
        raise fail(
            folder, f"none of the {len(records)} photos could be read ({reasons})", "Use JPEG, PNG or HEIC photos"
        )
    dets = [r.detection for r in readable if r.detection is not None]  # all of readable
    if any(len(d.ids) or (d.charuco_ids is not None and len(d.charuco_ids)) for d in dets):
        twice = [sorted({int(i) for i in d.ids if list(d.ids).count(i) > 1}) for d in dets if len(d.ids)]
        repeating = sum(bool(t) for t in twice)
        if repeating > len(twice) / 2:  # a tag seen twice in a photo is matched nowhere
            ids = sorted({i for t in twice for i in t})
            raise fail(
                folder,
                f"tag{'s' if len(ids) > 1 else ''} {', '.join(map(str, ids))} appear{'' if len(ids) > 1 else 's'} "
                f"more than once in {repeating} of {len(twice)} photos with tags: a photo's tags "
                "are told apart by their ids",
                "Print a sheet whose tags all differ (`nerfkit tags`)",
            )
        return
    search = _search_other_dictionaries(readable, dictionary, progress)
    finds = search.finds()
    if finds and finds[0].in_most:
        raise another_dictionary(folder, dictionary, f"found in any of {len(readable)} photos", finds)
    tried = ", ".join(n.replace("_1000", "_*") for n in SEARCH_DICTIONARIES)
    problem = f"no {dictionary} tags found in any of {len(readable)} photos (also tried {tried})"
    check = "check that the tags are in focus, fully visible and not too small (at least ~30 px wide)" + otherwise
    if not finds:
        raise fail(folder, problem, check[0].upper() + check[1:])
    few = finds[0]  # in few photos: perhaps a pattern misread as a tag
    shown = shown_names([search.names[k] for k in few.shown_in])
    raise fail(
        folder,
        f"{problem}; {few.name} reads {_ids_text(few.ids)} in {few.photos} of them ({shown}): a tag, or a "
        "pattern misread as one",
        f"If {'it is a tag' if few.photos == 1 else 'they are tags'}, re-run with --dict {few.name}; else {check}",
    )


def _search_other_dictionaries(readable: list[PhotoRecord], dictionary: str, progress: bool) -> DictionarySearch:
    """Other dictionaries' tags in a sample of the photos, then, unless most of the sample
    shows one's, in the rest."""
    search = DictionarySearch(skip=dictionary)
    first = spread(len(readable))
    where = f"{len(first)} of them" if len(first) < len(readable) else "them"
    _say(
        progress,
        f"no {dictionary} tags in any of {len(readable)} photos: looking for other dictionaries' tags in {where}...",
    )
    _search_photos(search, [readable[i].path for i in first])
    rest = [r.path for i, r in enumerate(readable) if i not in first]
    if rest and not any(f.in_most for f in search.finds()):
        _say(progress, f"not in most of them: looking in the other {len(rest)} photos...")
        _search_photos(search, rest)
    return search


def _search_photos(search: DictionarySearch, paths: list[Path]) -> None:
    """Add each photo that loads to ``search`` (one at a time: only its small copy is kept)."""
    for path in paths:
        image = _load_quietly(path)
        if image is not None:
            search.add(image, path.name)


def _load_quietly(path: Path) -> np.ndarray | None:
    """The upright photo, or None when it cannot be read (its scan says why)."""
    try:
        return load_image_uint8(path)
    except (NerfkitError, MemoryError):
        return None


def probe_sample(
    files: list[Path], folder: str | Path, dictionary: str, detect_side: int = 2000, progress: bool = True
) -> None:
    """Before the scan of every photo: refuse at once when a few photos spread through
    ``files`` show no tag of ``dictionary`` while most of them show another dictionary's."""
    sample = [files[i] for i in spread(len(files))]
    detector, bits = make_detector(dictionary), marker_bits(dictionary)
    search = DictionarySearch(skip=dictionary)
    for path in sample:
        image = _load_quietly(path)
        if image is None:
            continue
        if len(detect(image, detector, detect_side, bits).ids):
            return  # tags of the dictionary asked for: scan as asked
        if not search.photos:
            _say(
                progress,
                f"looking for {dictionary} and other dictionaries' tags in {len(sample)} of the {len(files)} photos...",
            )
        search.add(image, path.name)
    finds = search.finds()
    if finds and finds[0].in_most:
        whole = len(sample) == len(files)
        looked = (
            f"in any of the {len(files)} photos"
            if whole
            else f"in {search.photos} photos spread through the {len(files)}"
        )
        raise another_dictionary(folder, dictionary, looked, finds)


def another_dictionary(folder: str | Path, dictionary: str, looked: str, finds: list[DictionaryFind]) -> NerfkitError:
    """The error for photos showing no tag of ``dictionary`` (``looked``: where) but, in most
    of those searched, tags of the dictionaries of ``finds`` (best first)."""
    best = finds[0]
    found = (
        f"{best.name} tags are there ({_ids_text(best.ids)}, in {best.photos} of the {best.searched} photos searched"
    )
    if best.misreads:
        found += f"; also {_ids_text(best.misreads)} in fewer, likely misread"
    found += ")"
    others = ", ".join(f"{f.name} ones ({_ids_text(f.ids)}, in {f.photos})" for f in finds[1:3])
    if others:
        found += f", and {others}"
    return fail(folder, f"no {dictionary} tags {looked}, but {found}", f"Re-run with --dict {best.name}")


def _ids_text(ids: list[int]) -> str:
    """Ids as words: "id 7", or "ids 0, 1, 2, 3, 4, 5 and 4 more"."""
    return f"id {ids[0]}" if len(ids) == 1 else "ids " + shown_names([str(i) for i in ids], 6)


def spread(count: int, n: int = SAMPLE_PHOTOS) -> list[int]:
    """Indices of ``n`` of ``count`` items spread evenly through them, first and last
    included (all of them when there are no more than ``n``)."""
    if count <= n:
        return list(range(count))
    return [int(i) for i in np.linspace(0, count - 1, n).round()]


def _say(progress: bool, line: str) -> None:
    """One line on stderr saying what slow work starts (none without ``progress``)."""
    if progress:
        print(line, file=sys.stderr, flush=True)


def frame_turns(records: list[PhotoRecord], size: tuple[int, int] | None = None) -> int | None:
    """The frame of ``records`` (those of ``size``; default all): clockwise quarter turns
    from the sensor's pixels, counting those :func:`turn_into_frame` added
    (:func:`~nerfkit.images.common_frame`)."""
    chosen = [r for r in records if r.detection is not None and (size is None or r.size == tuple(size))]
    return common_frame([r.orientation for r in chosen], [r.turns for r in chosen])


def turn_into_frame(r: PhotoRecord, frame: int | None) -> str:
    """Turn a photo held the other way (upright size transposed) into ``frame``
    (:func:`~nerfkit.images.turns_into_frame`), detection included (``r.turns`` records
    how). Returns "" when done, else why it cannot be."""
    turns = turns_into_frame(r.orientation, frame)
    if turns is None:
        return (
            "no EXIF orientation says how the camera's photos were held"
            if frame is None
            else "no EXIF orientation says which way it was turned (rotated in an editor?)"
        )
    r.turns = turns
    assert r.detection is not None  # only photos that were read have a size to turn
    r.detection = r.detection.turned(turns)
    return ""


def keep_one_lens(records: list[PhotoRecord], lens: float | None = None) -> list[PhotoRecord]:
    """The photos taken with one lens: EXIF focal length (35 mm equivalent) ``lens``,
    default the most common. Photos of another lens or zoom are skipped with the reason
    (:func:`~.camera.other_lens`); photos without the EXIF tag are kept."""
    from .camera import common_lens, other_lens

    if lens is None:
        lens = common_lens(r.exif_f35 for r in records if r.detection is not None)
    kept = []
    for r in records:
        why = other_lens(r.exif_f35, lens)
        if why:
            r.skip(why)
        else:
            kept.append(r)
    return kept


def group_by_size(
    records: list[PhotoRecord], turn: bool = False, resize: bool = False
) -> tuple[tuple[int, int] | None, list[PhotoRecord]]:
    """The photo size most detected photos share, and the photos of that size.

    A photo of the transposed size was held the other way. With ``turn``, such a photo
    whose EXIF orientation says how it was held is turned into the others' frame
    (:func:`turn_into_frame`) and kept: its pixels are then the sensor's, as the others',
    so one camera fits them all. Without ``turn``, or with no such EXIF (a photo rotated
    in an editor), it is skipped with the reason. With ``resize``, a photo of the same shape
    at another size (a phone's other resolution, a copy resized by an app) has its detection
    resized to the common size and is kept (``info["resized_from"]``); without, it is skipped.
    """
    main = common_size(r.size for r in records if r.detection is not None)
    if main is None:
        return None, []
    main_turns = frame_turns(records, main)
    kept = []
    for r in records:
        if r.detection is None:
            continue
        if r.size == main:
            kept.append(r)
        elif r.size == (main[1], main[0]):
            why = turn_into_frame(r, main_turns) if turn else "photos held the other way need their own calibration"
            if not why:
                kept.append(r)
                continue
            r.skip(f"{held_as(*r.size)} while most photos are {main[0]}x{main[1]}: {why}")
        elif resize and abs(r.detection.width * main[1] / (r.detection.height * main[0]) - 1) < 0.01:  # one shape
            r.info["resized_from"] = f"{r.detection.width}x{r.detection.height}"
            r.detection = r.detection.resized(*main)
            kept.append(r)
        else:
            r.skip(f"size {r.detection.width}x{r.detection.height} differs from most photos ({main[0]}x{main[1]})")
    return main, kept


def blur_hint(records: list[PhotoRecord], rec: PhotoRecord) -> str:
    """' (looks blurred: ...)' when the photo is much less sharp than the folder's median."""
    values = [r.detection.sharpness for r in records if r.detection is not None]
    if rec.detection is None or len(values) < 3:
        return ""
    med = float(np.median(values))
    if med > 0 and rec.detection.sharpness < 0.3 * med:
        return f" (looks blurred: sharpness {rec.detection.sharpness:.0f} vs median {med:.0f})"
    return ""


def default_jobs() -> int:
    return max(1, min(4, os.cpu_count() or 1))
