"""The small lookups the one-machine commands and the jobs make (app/local.py, app/jobs/)."""

from __future__ import annotations

from app import crud
from app.crud.assignments import is_assigned
from app.models import Sequence


def test_datasets_sequence_at_path_is_the_newest_registered_there(db, factory):
    first = factory.registered_sequence("a")
    with db.write() as s:
        path = s.get(Sequence, first).path
        second = crud.create_dataset(s, factory.sequence_folder("b"), "b", "kitti", None, None)[1]
        second.path = path  # registered twice: the newer one is meant
        s.commit()
        second_id = second.id
    with db.read() as s:
        assert crud.sequence_at_path(s, path).id == second_id
        assert crud.sequence_at_path(s, path + "x") is None
        assert crud.sequence_paths(s) == [(first, path), (second_id, path)]


def test_datasets_ready_sequence_ids_leave_out_the_others(db, factory):
    ready = factory.ingested_sequence(n_frames=3, n_objects=1, name="ready")
    factory.registered_sequence("registered")
    with db.read() as s:
        assert crud.ready_sequence_ids(s) == [ready]


def test_users_id_and_role_by_name(db, factory):
    admin = factory.user("admin", name="root")
    with db.read() as s:
        assert crud.user_id_by_name(s, "root") == admin.id and crud.user_id_by_name(s, "nobody") is None
        assert crud.user_role(s, admin.id) == "admin" and crud.user_role(s, None) is None


def test_assignments_is_assigned_per_user_and_sequence(db, factory):
    seq = factory.registered_sequence()
    a, b = factory.user("operator"), factory.user("operator")
    factory.assign(a, seq)
    with db.read() as s:
        assert is_assigned(s, a.id, seq) and not is_assigned(s, b.id, seq)
