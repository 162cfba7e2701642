"""LeRobot v3 datasets (``codebase_version`` "v3.0"), written and read without LeRobot.

Why not LeRobot itself: it pins torch, torchvision, torchcodec, datasets and more, which
would fight the project's pinned torch; the format is files (parquet, JSON, MP4) that
pyarrow and PyAV write and read alone. The layout follows LeRobot's own source
(``datasets/utils.py``, ``dataset_metadata.py``, ``dataset_writer.py``,
``compute_stats.py``, ``video_utils.py``); docs/notes/data.md says what was checked
against its loader.

Layout of a dataset folder::

    meta/info.json                 codebase_version, fps, features, paths, totals, splits
    meta/stats.json                per feature: min max mean std count q01 q10 q50 q90 q99
    meta/tasks.parquet             task (the pandas index) -> task_index
    meta/episodes/chunk-000/file-000.parquet   one row per episode: length, tasks,
                                   dataset_from/to_index, data (and video) chunk/file, ...
    meta/testbed.json              the testbed's codes (modes, intervention) and sources
    data/chunk-CCC/file-FFF.parquet            the frames, one row group per episode
    videos/observation.images.top/chunk-CCC/file-FFF.mp4   (--images video)

Files roll over (at an episode boundary) near LeRobot's sizes: 100 MB of data, 200 MB
of video, 1000 files a chunk. With ``--images png`` each frame's PNG bytes are in the
data parquet (LeRobot's ``image`` dtype: struct<bytes, path>); with ``--images video``
every episode of a file is one run of frames of one MP4 stream, frame k of the file at
pts k / fps, so an episode's frames are ``from_timestamp + timestamp``, as LeRobot reads
them. The codec and the MP4 files are ``testbed.datasets.video``'s, meta/stats.json's
numbers ``testbed.datasets.stats``'; what goes in is ``testbed.datasets.episodes``'
model. The verbs reach this module through ``testbed.datasets.dataset_io``, which
imports it only once the ``export`` extra is known to be there.
"""

from __future__ import annotations

import io
import itertools
import json
import os
import shutil
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Final

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from testbed.core.config import ConfigError
from testbed.datasets.class_columns import CLASS_NAMES, OUTCOME_NAMES
from testbed.datasets.episodes import (
    COLUMNS,
    ESSENTIAL,
    FPS,
    IMAGE_SHAPE,
    INDEX_COLUMNS,
    Episode,
    Frames,
    Numbering,
    read_back,
)
from testbed.datasets.stats import Stats
from testbed.datasets.video import (
    VIDEO,
    VideoCodec,
    VideoFile,
    check_codec,
    decode_video,
    video_info,
)

CODEBASE_VERSION: Final = "v3.0"
IMAGE_KEY: Final = "observation.images.top"
CHUNK_FILE: Final = "chunk-{chunk_index:03d}/file-{file_index:03d}"
DATA_PATH: Final = "data/" + CHUNK_FILE + ".parquet"
VIDEO_PATH: Final = "videos/{video_key}/" + CHUNK_FILE + ".mp4"
EPISODES_PATH: Final = "meta/episodes/" + CHUNK_FILE + ".parquet"
TASKS_PATH: Final = "meta/tasks.parquet"
CHUNKS_SIZE: Final = 1000
DATA_FILE_MB: Final = 100
VIDEO_FILE_MB: Final = 200
PNG_LEVEL: Final = 6
"""zlib level of the PNGs (LeRobot's for ``image`` features); bench_export.py."""
NAMES: Final[dict[str, list[str]]] = {"action": ["face"], "goal": ["x", "y"],
                                      "frame_class": CLASS_NAMES,
                                      "episode_outcome": OUTCOME_NAMES}
"""info.json's ``names`` of a feature: its entries' names, or a code's meaning by value
(``frame_class`` 4 is ``names[4]``, "pre_intervention")."""


# ----------------------------------------------------------------- the schema
def _arrow(dtype: str, shape: tuple[int, ...]) -> pa.DataType:
    base = pa.from_numpy_dtype(np.dtype(dtype))
    return pa.list_(base, shape[0]) if shape else base


def _hf(dtype: str, shape: tuple[int, ...]) -> dict[str, Any]:
    """The column as Hugging Face ``datasets`` describes it (parquet metadata), so a
    plain ``datasets.load_dataset("parquet")`` decodes it as LeRobot's loader does."""
    value = {"dtype": dtype, "_type": "Value"}
    return {"feature": value, "length": shape[0], "_type": "Sequence"} if shape else value


def _schema(png: bool) -> pa.Schema:
    fields, hf = [], {}
    if png:
        fields.append(pa.field(IMAGE_KEY, pa.struct([("bytes", pa.binary()),
                                                     ("path", pa.string())])))
        hf[IMAGE_KEY] = {"_type": "Image"}
    for name, dtype, shape in COLUMNS:
        fields.append(pa.field(name, _arrow(dtype, shape)))
        hf[name] = _hf(dtype, shape)
    for name, dtype in INDEX_COLUMNS:
        fields.append(pa.field(name, _arrow(dtype, ())))
        hf[name] = _hf(dtype, ())
    meta = {"huggingface": json.dumps({"info": {"features": hf}})}
    return pa.schema(fields, metadata=meta)


def features(png: bool, video_info: dict[str, Any] | None = None) -> dict[str, Any]:
    """``info.json``'s features: dtype, shape, names (and the video's info)."""
    image: dict[str, Any] = {"dtype": "image" if png else "video", "shape": list(IMAGE_SHAPE),
                             "names": ["height", "width", "channels"]}
    if not png:
        image["info"] = video_info or {}
    out = {IMAGE_KEY: image}
    for name, dtype, shape in COLUMNS:
        out[name] = {"dtype": dtype, "shape": list(shape) or [1], "names": NAMES.get(name)}
    for name, dtype in INDEX_COLUMNS:
        out[name] = {"dtype": dtype, "shape": [1], "names": None}
    return out


# ----------------------------------------------------------------- images
def encode_png(image: np.ndarray, level: int = PNG_LEVEL) -> bytes:
    from PIL import Image  # Pillow comes with matplotlib, a dependency

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG", compress_level=level)
    return buf.getvalue()


def decode_png(data: bytes) -> np.ndarray:
    from PIL import Image

    with Image.open(io.BytesIO(data)) as im:
        return np.asarray(im.convert("RGB"))


# ----------------------------------------------------------------- writing
def _next(chunk_file: tuple[int, int], chunks_size: int) -> tuple[int, int]:
    chunk, file = chunk_file
    return (chunk + 1, 0) if file + 1 >= chunks_size else (chunk, file + 1)


def _write_table(columns: dict[str, Any], path: Path,
                 metadata: dict[str, str] | None = None) -> None:
    table = pa.table(columns)
    if metadata:
        table = table.replace_schema_metadata(metadata)
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, path, compression="snappy")


def _tasks_metadata() -> dict[str, str]:
    """pandas' parquet metadata making ``task`` the index, as LeRobot's
    ``pd.read_parquet(meta/tasks.parquet)`` expects (written without pandas)."""
    return {"pandas": json.dumps({
        "index_columns": ["task"],
        "column_indexes": [{"name": None, "field_name": None, "pandas_type": "unicode",
                            "numpy_type": "object", "metadata": {"encoding": "UTF-8"}}],
        "columns": [{"name": "task_index", "field_name": "task_index",
                     "pandas_type": "int64", "numpy_type": "int64", "metadata": None},
                    {"name": "task", "field_name": "task", "pandas_type": "unicode",
                     "numpy_type": "object", "metadata": None}],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.0"})}


class _Writer:
    def __init__(self, root: Path, png: bool, fps: int, data_file_mb: float,
                 video_file_mb: float, chunks_size: int, png_level: int,
                 codec: VideoCodec) -> None:
        self.root, self.png, self.fps = root, png, fps
        self.data_limit = data_file_mb * 2**20
        self.video_limit = video_file_mb * 2**20
        self.chunks_size, self.png_level, self.codec = chunks_size, png_level, codec
        self.schema = _schema(png)
        self.data_at = (0, 0)
        self.video_at = (0, 0)
        self._pq: pq.ParquetWriter | None = None
        self._data_bytes = 0
        self._video: VideoFile | None = None
        self.first_video: Path | None = None
        self.stats = Stats()
        self.numbering = Numbering(fps)
        self.episodes: dict[str, list[Any]] = {}

    def _path(self, template: str, at: tuple[int, int]) -> Path:
        return self.root / template.format(video_key=IMAGE_KEY, chunk_index=at[0],
                                           file_index=at[1])

    def _table(self, ep: Episode, index: dict[str, np.ndarray]) -> pa.Table:
        arrays: list[pa.Array] = []
        if self.png:
            pngs = [encode_png(img, self.png_level) for img in ep.images]
            arrays.append(pa.StructArray.from_arrays(
                [pa.array(pngs, pa.binary()), pa.nulls(len(ep), pa.string())],
                names=["bytes", "path"]))
        for name, _, shape in COLUMNS:
            v = ep.columns[name]
            arrays.append(pa.FixedSizeListArray.from_arrays(pa.array(v.reshape(-1)), shape[0])
                          if shape else pa.array(v))
        arrays.extend(pa.array(index[name]) for name, _ in INDEX_COLUMNS)
        return pa.Table.from_arrays(arrays, schema=self.schema)

    def add(self, ep: Episode) -> None:
        index = self.numbering.number(ep)
        table = self._table(ep, index)
        if self._pq is not None and self._data_bytes + table.nbytes > self.data_limit:
            self._pq.close()
            self._pq, self._data_bytes = None, 0
            self.data_at = _next(self.data_at, self.chunks_size)
        if self._pq is None:
            path = self._path(DATA_PATH, self.data_at)
            path.parent.mkdir(parents=True, exist_ok=True)
            self._pq = pq.ParquetWriter(path, self.schema, compression="snappy")
        self._pq.write_table(table)  # one row group per episode
        self._data_bytes += table.nbytes
        self.stats.add({**ep.columns, **index}, ep.images)
        first = int(index["index"][0])
        row: dict[str, Any] = {
            "episode_index": int(index["episode_index"][0]), "tasks": [ep.task],
            "length": len(ep), "data/chunk_index": self.data_at[0],
            "data/file_index": self.data_at[1], "dataset_from_index": first,
            "dataset_to_index": first + len(ep)}
        if not self.png:
            row.update(self._add_video(ep.images))
        row.update({"meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0,
                    "source_index": ep.source_index, "robot": ep.robot,
                    "first_step": int(ep.columns["step"][0])})
        for k, v in row.items():
            self.episodes.setdefault(k, []).append(v)

    def _add_video(self, images: np.ndarray) -> dict[str, Any]:
        if self._video is not None and self._video.bytes >= self.video_limit:
            self._video.close()
            self._video = None
            self.video_at = _next(self.video_at, self.chunks_size)
        if self._video is None:
            self._video = VideoFile(self._path(VIDEO_PATH, self.video_at), self.fps, self.codec)
            self.first_video = self.first_video or self._video.path
        start = self._video.frames
        self._video.add(images)
        key = f"videos/{IMAGE_KEY}"
        return {f"{key}/chunk_index": self.video_at[0], f"{key}/file_index": self.video_at[1],
                f"{key}/from_timestamp": start / self.fps,
                f"{key}/to_timestamp": self._video.frames / self.fps}

    def close(self, meta: dict[str, Any]) -> None:
        if self._pq is not None:
            self._pq.close()
        if self._video is not None:
            self._video.close()
        tasks = list(self.numbering.tasks)
        _write_table({"task_index": pa.array(range(len(tasks)), pa.int64()),
                      "task": pa.array(tasks, pa.string())},
                     self.root / TASKS_PATH, _tasks_metadata())
        _write_table(self.episodes, self._path(EPISODES_PATH, (0, 0)))
        vinfo = video_info(self.first_video, self.codec) if self.first_video else None
        info = {
            "codebase_version": CODEBASE_VERSION, "robot_type": "fleet-dagger-pusher",
            "total_episodes": self.numbering.episodes,
            "total_frames": self.numbering.frames, "total_tasks": len(tasks),
            "chunks_size": self.chunks_size,
            "data_files_size_in_mb": self.data_limit / 2**20,
            "video_files_size_in_mb": self.video_limit / 2**20, "fps": self.fps,
            "splits": {"train": f"0:{self.numbering.episodes}"}, "data_path": DATA_PATH,
            "video_path": None if self.png else VIDEO_PATH,
            "features": features(self.png, vinfo)}
        for name, obj in (("info.json", info), ("stats.json", self.stats.result(IMAGE_KEY)),
                          ("testbed.json", meta)):
            (self.root / "meta" / name).write_text(json.dumps(obj, indent=2) + "\n")


def write_dataset(episodes: Iterable[Episode], out: Path, images: str, meta: dict[str, Any],
                  *, fps: int = FPS, data_file_mb: float = DATA_FILE_MB,
                  video_file_mb: float = VIDEO_FILE_MB, chunks_size: int = CHUNKS_SIZE,
                  png_level: int = PNG_LEVEL, codec: VideoCodec = VIDEO) -> tuple[int, int]:
    """Write ``episodes`` as a LeRobot v3 dataset at ``out`` (a new or empty folder),
    built in a temporary sibling and renamed at the end, so a failed export leaves
    nothing half-written. Returns (frames, episodes)."""
    if images == "video":
        check_codec(codec)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    try:
        w = _Writer(tmp, images == "png", fps, data_file_mb, video_file_mb, chunks_size,
                    png_level, codec)
        for ep in episodes:
            w.add(ep)
        w.close(meta)
        if out.exists():
            out.rmdir()  # empty: checked by the verb
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return w.numbering.frames, w.numbering.episodes


# ----------------------------------------------------------------- reading
def read_info(root: Path) -> dict[str, Any]:
    return json.loads((root / "meta" / "info.json").read_text())


def read_dataset(root: Path, flag: str = "--data") -> Frames:
    """A dataset of ``testbed export`` back in memory (every frame, images decoded)."""
    info = read_info(root)
    feats = info.get("features", {})
    if info.get("codebase_version") != CODEBASE_VERSION:
        raise ConfigError(f"{flag}: {root} is LeRobot {info.get('codebase_version')}, "
                          f"not {CODEBASE_VERSION}")
    missing = sorted(n for n in ESSENTIAL if n not in feats)
    if missing or IMAGE_KEY not in feats:
        raise ConfigError(f"{flag}: {root} is a LeRobot dataset without the testbed's "
                          f"columns ({', '.join(missing[:3]) or IMAGE_KEY}); give one "
                          "written by testbed export")
    files = sorted((root / "data").glob("chunk-*/file-*.parquet"))
    table = pa.concat_tables([pq.read_table(f) for f in files]).sort_by("index")
    cols: dict[str, np.ndarray] = {}
    for name, dtype, shape in COLUMNS:
        if name not in table.column_names:  # an older export's: read_back fills it
            continue
        col = table.column(name).combine_chunks()
        if shape:
            col = col.flatten()
        cols[name] = col.to_numpy(zero_copy_only=False).astype(dtype).reshape(-1, *shape)
    for name, dtype in INDEX_COLUMNS:
        cols[name] = table.column(name).to_numpy().astype(dtype)
    if feats[IMAGE_KEY]["dtype"] == "image":
        data = table.column(IMAGE_KEY).combine_chunks().field("bytes").to_pylist()
        images = (np.stack([decode_png(b) for b in data]) if data
                  else np.zeros((0, *IMAGE_SHAPE), np.uint8))
    else:
        images = _video_frames(root, info, cols["episode_index"], cols["frame_index"])
    tasks = pq.read_table(root / TASKS_PATH).sort_by("task_index").column("task").to_pylist()
    meta_path = root / "meta" / "testbed.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    return read_back(Frames(cols, images, [str(t) for t in tasks]),
                     meta if isinstance(meta, dict) else {}, str(root))


def _video_frames(root: Path, info: dict[str, Any], episode: np.ndarray,
                  frame: np.ndarray) -> np.ndarray:
    eps = pa.concat_tables([pq.read_table(f) for f in sorted(
        (root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))]).to_pydict()
    fps = int(info["fps"])
    key = f"videos/{IMAGE_KEY}"
    by_episode = {e: i for i, e in enumerate(eps["episode_index"])}
    decoded: dict[tuple[int, int], np.ndarray] = {}
    out = np.zeros((len(episode), *IMAGE_SHAPE), np.uint8)
    bounds = np.flatnonzero(np.r_[True, episode[1:] != episode[:-1], True])
    for lo, hi in itertools.pairwise(bounds):
        i = by_episode[int(episode[lo])]
        at = (int(eps[f"{key}/chunk_index"][i]), int(eps[f"{key}/file_index"][i]))
        if at not in decoded:
            path = root / info["video_path"].format(video_key=IMAGE_KEY, chunk_index=at[0],
                                                    file_index=at[1])
            decoded[at] = decode_video(path, fps)
        start = round(float(eps[f"{key}/from_timestamp"][i]) * fps)
        out[lo:hi] = decoded[at][start + frame[lo:hi]]
    return out
