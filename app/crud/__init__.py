"""Database operations used by routes, jobs and the CLI, one module per resource. Routes stay thin
and call these; `from app import crud` then `crud.apply_action(...)` reaches every one.

Write operations take a session from `Database.write` (BEGIN IMMEDIATE on SQLite) and commit
themselves; on PostgreSQL they lock the rows they change (`FOR UPDATE`).
"""

from __future__ import annotations

from app.crud.assignments import create_assignment, delete_assignment, list_assignments
from app.crud.bulk import bulk_accept, bulk_preview, list_bulk_actions, operation_count, undo_bulk
from app.crud.bulk_load import BULK_TABLES, analyze_tables, clear_sequence_rows, vacuum_after_bulk_load
from app.crud.datasets import (
    check_ready,
    check_sensor_file,
    check_tree_inside_roots,
    create_dataset,
    dataset_sequences,
    get_dataset,
    get_sequence,
    list_datasets,
    list_sequences,
    pipeline_config,
    registered_sequence_id,
    require_ready,
    resolve_registration_path,
    sequence_label_set,
    sequence_stats,
)
from app.crud.jobs import cancel_job, create_job, get_job, list_jobs
from app.crud.review import (
    REVIEW_ACTIONS,
    REVIEW_FIELDS,
    ReviewAction,
    apply_action,
    initial_review_state,
    last_undoable_event,
    rebuild_review_state,
    refresh_labels,
    review_state,
)
from app.crud.review_queue import lease_next_track, lease_track, queue_priority, release_lease
from app.crud.statistics import (
    constraints_query,
    labels_query,
    progress_stats,
    track_label_rows,
    verified_constraints_query,
)
from app.crud.tracks import TRACK_SORTS, TrackFilter, get_track, list_tracks, track_events, track_segments
from app.crud.users import (
    AuthUser,
    create_token,
    create_user,
    get_user,
    get_user_by_name,
    list_tokens,
    list_users,
    revoke_tokens,
    set_user_active,
    user_for_token,
)

__all__ = [
    "get_user",
    "list_users",
    "dataset_sequences",
    "get_dataset",
    "get_sequence",
    "list_datasets",
    "list_sequences",
    "get_job",
    "list_jobs",
    "pipeline_config",
    "bulk_accept",
    "bulk_preview",
    "list_bulk_actions",
    "operation_count",
    "undo_bulk",
    "create_assignment",
    "list_assignments",
    "delete_assignment",
    "AuthUser",
    "create_user",
    "create_token",
    "user_for_token",
    "get_user_by_name",
    "revoke_tokens",
    "set_user_active",
    "list_tokens",
    "resolve_registration_path",
    "check_tree_inside_roots",
    "check_sensor_file",
    "registered_sequence_id",
    "sequence_label_set",
    "create_dataset",
    "sequence_stats",
    "check_ready",
    "require_ready",
    "create_job",
    "cancel_job",
    "TrackFilter",
    "list_tracks",
    "get_track",
    "track_segments",
    "track_events",
    "TRACK_SORTS",
    "review_state",
    "initial_review_state",
    "rebuild_review_state",
    "apply_action",
    "last_undoable_event",
    "refresh_labels",
    "REVIEW_ACTIONS",
    "ReviewAction",
    "REVIEW_FIELDS",
    "lease_next_track",
    "lease_track",
    "release_lease",
    "queue_priority",
    "clear_sequence_rows",
    "analyze_tables",
    "vacuum_after_bulk_load",
    "BULK_TABLES",
    "progress_stats",
    "constraints_query",
    "verified_constraints_query",
    "labels_query",
    "track_label_rows",
]
