from __future__ import annotations

from app import crud
from app.crud.model_versions import newest_model_trained_on
from app.models import ModelVersion


def _model(db, params) -> int:
    with db.write() as s:
        mv = ModelVersion(name="m", kind="train", path="m.pt", config={"params": params})
        s.add(mv)
        s.commit()
        return mv.id


def test_model_versions_newest_trained_on_reads_train_and_finetune_params(db):
    train = _model(db, {"sequence_ids": [1, 2]})
    finetune = _model(db, {"sequence_id": 2})
    _model(db, {"sequence_ids": [3]})
    with db.read() as s:
        assert newest_model_trained_on(s, 1).id == train
        assert newest_model_trained_on(s, 2).id == finetune
        assert newest_model_trained_on(s, 4) is None
        assert crud.newest_model_path(s) == "m.pt"


def test_model_versions_newest_path_is_none_without_models(db):
    with db.read() as s:
        assert crud.newest_model_path(s) is None
