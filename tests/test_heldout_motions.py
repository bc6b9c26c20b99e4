"""experiments/heldout_motions.py: the totals it reports, on a table with a known answer."""
from pathlib import Path

import pandas as pd

from experiments.heldout_motions import COUNTS, MOTIONS, summary, totals


def _rows(set_, frames, detached, method="ours"):
    row = {k: 0 for k in COUNTS}
    row.update({"set": set_, "method": method, "frames": frames, "frames_with_detached": detached})
    return row


def test_totals_sum_the_default_method_per_set_and_give_shares_of_frames(tmp_path):
    df = pd.DataFrame([_rows("tuning", 100, 1), _rows("tuning", 300, 3), _rows("heldout", 50, 5),
                       _rows("tuning", 100, 100, method="keypoints")])
    t = totals(df)
    assert t["tuning"]["frames"] == 400 and t["tuning"]["items"] == 2
    assert t["tuning"]["share_with_detached"] == 0.01 and t["heldout"]["share_with_detached"] == 0.1
    tuned = tmp_path / "reshape_eval.csv"
    pd.DataFrame([_rows("tuning", 200, 0), _rows("heldout", 10, 1)]).to_csv(tuned, index=False)
    s = summary(df, tuned)
    assert s["tuning"]["tuned_frames"] == 200 and s["heldout"]["tuned_share_with_detached"] == 0.1
    assert "tuned_frames" not in summary(df, tmp_path / "absent.csv")["tuning"]


def test_none_of_the_motions_is_one_the_method_was_tuned_on():
    from nnsf import params

    tuned = params.load(Path(__file__).resolve().parents[1] / "params.yaml")["reshape_eval"]["motions"]
    assert len(MOTIONS) == 6 and not set(MOTIONS) & set(tuned)
