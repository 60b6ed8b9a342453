import pickle

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import _eval_dataset as E  # noqa: E402

from holodata.dataset import open_dataset  # noqa: E402
from holodata.torch import HeatmapDataset, HeatmapNorm, SampleTransform  # noqa: E402
from holodata.torch.train import _collate  # noqa: E402


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return E.build(str(tmp_path_factory.mktemp("ds") / "tiny.zarr"))


def test_items_and_split_by_scene(dataset):
    tr = HeatmapDataset(dataset, split="train")
    te = HeatmapDataset(open_dataset(dataset), split="test", norm=tr.norm)
    assert tr.scenes == ["room_a", "room_b"] and te.scenes == ["room_c"]
    assert len(tr) == 8 and len(te) == 4
    assert not {s for s, _ in tr.index} & {s for s, _ in te.index}
    s = tr[5]
    assert s["heatmap"].shape == (E.BINS.n, E.GRID.H, E.GRID.W) and s["heatmap"].dtype == torch.float32
    assert float(s["heatmap"].min()) >= -1 and float(s["heatmap"].max()) <= 1
    raw = open_dataset(dataset).scene(s["scene"])
    np.testing.assert_array_equal(s["range"].numpy(), np.asarray(raw["gt/range"][s["frame"]]))
    np.testing.assert_allclose(s["heatmap"].numpy(), tr.norm(np.asarray(raw["radar/heatmap"][s["frame"]])))
    small = HeatmapDataset(dataset, split="train", transform=SampleTransform(downsample=2, range_pool=2))
    assert small[0]["heatmap"].shape == (E.BINS.n // 2, E.GRID.H // 2, E.GRID.W // 2)


def test_multiprocess_workers_match_single_process(dataset):
    ds = HeatmapDataset(dataset, split="train", norm=HeatmapNorm())
    clone = pickle.loads(pickle.dumps(ds))
    assert clone._ds is None  # store handle dropped, reopened lazily in the worker
    one = list(torch.utils.data.DataLoader(ds, batch_size=4, num_workers=0, collate_fn=_collate))
    two = list(torch.utils.data.DataLoader(ds, batch_size=4, num_workers=2, collate_fn=_collate))
    assert len(one) == len(two) == 2
    for a, b in zip(one, two):
        assert a["scene"] == b["scene"] and a["frame"] == b["frame"]
        torch.testing.assert_close(a["heatmap"], b["heatmap"])
        torch.testing.assert_close(a["range"], b["range"], equal_nan=True)
