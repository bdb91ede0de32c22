"""`tracklabel db ...` and `tracklabel user ...`: migrations, operators, admins and their tokens."""

from __future__ import annotations

from typing import Annotated

import typer

from app.cli_common import fail, friendly_errors, service_call

db_app = typer.Typer(no_args_is_help=True, help="Database migrations.")
user_app = typer.Typer(no_args_is_help=True, help="Operators, admins and their tokens.")


@db_app.command("upgrade")
@friendly_errors
def db_upgrade(
    revision: Annotated[str, typer.Option(help="Target revision.")] = "head",
    wait: Annotated[float, typer.Option(help="Seconds to wait for the database to come up.")] = 0.0,
) -> None:
    """Wait for the database (TRACKLABEL_DATABASE_URL), then upgrade it to `revision`."""
    from app.core.config import get_settings
    from app.core.db import make_engine, wait_for_db
    from app.core.migrate import upgrade

    settings = get_settings()
    if wait > 0:
        engine = make_engine(settings.db_url)
        wait_for_db(engine, timeout_s=wait)
        engine.dispose()
    upgrade(settings.db_url, revision)
    typer.echo(f"database at {revision}")


@db_app.command("downgrade")
@friendly_errors
def db_downgrade(revision: Annotated[str, typer.Argument(help="Target revision, e.g. base or -1.")]) -> None:
    """Downgrade the database to `revision`."""
    from app.core.config import get_settings
    from app.core.migrate import downgrade

    downgrade(get_settings().db_url, revision)
    typer.echo(f"database at {revision}")


def _user_db():  # -> (Settings, Database), the database upgraded first
    from app.core.config import get_settings
    from app.core.db import Database
    from app.core.migrate import upgrade

    settings = get_settings()
    upgrade(settings.db_url)
    return settings, Database.from_settings(settings)


ExpiresDays = Annotated[
    float | None, typer.Option(help="Days the token is valid (default: TRACKLABEL_TOKEN_EXPIRY_DAYS, 90).")
]


@user_app.command("add")
@friendly_errors
def user_add(
    name: Annotated[str, typer.Argument(help="User name.")],
    role: Annotated[str, typer.Option(help="operator, reviewer or admin.")] = "operator",
    expires_days: ExpiresDays = None,
) -> None:
    """Create a user and print their bearer token (shown once; only its hash is stored)."""
    from app import crud

    settings, db = _user_db()
    days = expires_days or settings.token_expiry_days
    with db.write() as s:
        result = service_call(lambda: crud.create_user(s, name, role, expires_days=days))
    db.dispose()
    assert isinstance(result, tuple)
    typer.echo(result[1])


@user_app.command("token")
@friendly_errors
def user_token(name: Annotated[str, typer.Argument(help="User name.")], expires_days: ExpiresDays = None) -> None:
    """Issue another token for a user and print it (shown once)."""
    from app import crud

    settings, db = _user_db()
    days = expires_days or settings.token_expiry_days
    with db.write() as s:
        token = service_call(lambda: crud.create_token(s, crud.get_user_by_name(s, name).id, None, days))
    db.dispose()
    typer.echo(token)


@user_app.command("revoke")
@friendly_errors
def user_revoke(
    name: Annotated[str | None, typer.Argument(help="Revoke every live token of this user.")] = None,
    token_prefix: Annotated[str | None, typer.Option(help="Revoke the live tokens starting with this (>= 6 chars).")] = None,
) -> None:
    """Revoke tokens: all of a user's, or those starting with --token-prefix. Refused from the next request on."""
    from app import crud

    if (name is None) == (token_prefix is None):
        fail("give a user NAME or --token-prefix, not both")
    _, db = _user_db()
    with db.write() as s:
        if name is not None:
            n = service_call(lambda: crud.revoke_tokens(s, user_id=crud.get_user_by_name(s, name).id))
        else:
            n = service_call(lambda: crud.revoke_tokens(s, prefix=token_prefix))
    db.dispose()
    typer.echo(f"revoked {n} token(s)")


def _set_active(name: str, active: bool) -> None:
    from app import crud

    _, db = _user_db()
    with db.write() as s:
        service_call(lambda: crud.set_user_active(s, crud.get_user_by_name(s, name).id, active))
    db.dispose()
    typer.echo(f"{name} {'enabled' if active else 'disabled'}")


@user_app.command("disable")
@friendly_errors
def user_disable(name: Annotated[str, typer.Argument(help="User name.")]) -> None:
    """Deactivate a user: all their tokens are refused from the next request on."""
    _set_active(name, False)


@user_app.command("enable")
@friendly_errors
def user_enable(name: Annotated[str, typer.Argument(help="User name.")]) -> None:
    """Reactivate a disabled user."""
    _set_active(name, True)
