"""`shadowless rig user`: the people who may log in to a rig's console, and their roles.

Works on the rig directory itself (``users.json``, :mod:`coordinator.users`), so it needs no
running coordinator; one that serves the rig re-reads the file when it changes, so a new user
may log in at once, and a changed role, a removal or a new password holds at that user's next
request (a removal or a new password ends their open sessions). Each command says which of these applies.
"""
from __future__ import annotations

import argparse
import getpass
import json
import sys
from pathlib import Path

from coordinator.rig_lock import holder
from coordinator.users import MIN_PASSWORD, ROLES, UserError, UserStore, check_name

EXAMPLES = f"""\
roles:
  viewer    sees everything the console shows, acts on nothing
  operator  acts: shows, plays, stops, blacks out, fires cues, runs jobs
  admin     an operator who also manages the users, here or in the console's People panel
            (a login with the rig token is an admin)

examples:
  shadowless rig user add alice --role operator --rig-dir rigs/table     # asks for the password twice
  shadowless rig user add bob --role viewer --password-file bob.txt      # in the rig directory
  shadowless rig user list --rig-dir rigs/table
  shadowless rig user role bob operator --rig-dir rigs/table
  shadowless rig user password alice --rig-dir rigs/table
  shadowless rig user rm bob --rig-dir rigs/table

Passwords are at least {MIN_PASSWORD} characters and are stored as scrypt hashes in RIG_DIR/users.json
(mode 0600). A running coordinator picks every change up by itself: no restart.
"""


def configure(p: argparse.ArgumentParser) -> None:
    """The ``user`` action of ``shadowless rig``."""
    p.description = ("Manage who may log in to the rig's console, by name and password, and what they may do. "
                     "Works on the rig directory; a running coordinator picks changes up by itself.")
    p.epilog = EXAMPLES
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    sub = p.add_subparsers(dest="user_command", metavar="ACTION", required=True)

    def rig_dir(q: argparse.ArgumentParser) -> None:
        q.add_argument("--rig-dir", metavar="DIR", default=None,
                       help="the rig directory (default: the current directory, if it holds rig.toml)")

    add = sub.add_parser("add", help="add a user with a role and a password")
    add.add_argument("name", help="1-32 letters, digits, '_', '.', '-' or '@' (kept in lower case)")
    add.add_argument("--role", default="viewer", choices=ROLES, help="what the user may do (default: viewer)")
    add.add_argument("--password-file", metavar="FILE",
                     help="read the password from the first line of FILE ('-': standard input) instead of asking")
    rig_dir(add)
    ls = sub.add_parser("list", help="list the users and their roles")
    ls.add_argument("--json", action="store_true", help="print JSON")
    rig_dir(ls)
    rm = sub.add_parser("rm", help="remove a user (their open console sessions end at their next request)")
    rm.add_argument("name")
    rig_dir(rm)
    role = sub.add_parser("role", help="give a user another role")
    role.add_argument("name")
    role.add_argument("role", choices=ROLES)
    rig_dir(role)
    pw = sub.add_parser("password", help="set a user's password")
    pw.add_argument("name")
    pw.add_argument("--password-file", metavar="FILE",
                    help="read the password from the first line of FILE ('-': standard input) instead of asking")
    rig_dir(pw)


def _rig_dir(given: str | None) -> Path:
    path = Path(given) if given else Path.cwd()
    if not (path / "rig.toml").is_file():
        if given:
            raise UserError(f"{path} is not a rig directory (no rig.toml)")
        raise UserError("the current directory holds no rig.toml: give the rig with --rig-dir DIR")
    return path


def _password(file: str | None) -> str:
    """The new password: the first line of ``file`` ('-': standard input), or typed twice without echo."""
    if file is not None:
        try:
            text = sys.stdin.readline() if file == "-" else Path(file).read_text()
        except OSError as exc:
            raise UserError(f"cannot read the password file {file}: {exc.strerror or exc}") from None
        return text.splitlines()[0] if text.splitlines() else ""
    if not sys.stdin.isatty():
        raise UserError("no terminal to type the password in: give it with --password-file FILE ('-': standard input)")
    first = getpass.getpass("password: ")
    if getpass.getpass("again: ") != first:
        raise UserError("the two passwords differ; nothing was changed")
    return first


def _served(path: Path, when: str) -> str:
    """What a running coordinator does with the change, in one sentence."""
    held = holder(path)
    if held is not None and held[1] == "coordinator":
        pid = f" (pid {held[0]})" if held[0] else ""
        return f"the coordinator serving this rig{pid} applies it {when}, no restart needed"
    return "no coordinator serves this rig now: the console uses it once one starts"


def run(args: argparse.Namespace) -> int:
    try:
        path = _rig_dir(args.rig_dir)
        store = UserStore(path)
        cmd = args.user_command
        if cmd == "list":
            users = store.list()
            if store.error:
                raise UserError(store.error)
            if args.json:
                json.dump([{"name": u.name, "role": u.role.value, "created": u.created, "changed": u.changed}
                           for u in users], sys.stdout, indent=2)
                print()
                return 0
            if not users:
                print(f"no users in {path}: everyone logs in with the rig token; add one with "
                      "`shadowless rig user add NAME --role operator`")
                return 0
            width = max(len(u.name) for u in users)
            for u in users:
                print(f"{u.name:<{width}}  {u.role.value:<8}  changed {u.changed.replace('T', ' ')}")
            print(f"{len(users)} user{'s' if len(users) != 1 else ''}")
            return 0
        if cmd in ("add", "password"):      # refused before the password is asked for
            name = check_name(args.name)
            if cmd == "add" and store.role_of(name) is not None:
                raise UserError(f"user {name!r} exists already; change it with `shadowless rig user role {name} "
                                f"ROLE` or `shadowless rig user password {name}`")
            if cmd == "password" and store.role_of(name) is None:
                raise UserError(f"no user {name!r}; add one with `shadowless rig user add {name} --role ROLE`")
        if cmd == "add":
            said = store.add(args.name, args.role, _password(args.password_file))
            print(f"{said}; {_served(path, 'at once: they may log in now')}")
        elif cmd == "rm":
            said = store.remove(args.name)
            print(f"{said}; {_served(path, 'at their next request (their sessions end)')}")
        elif cmd == "role":
            said = store.set_role(args.name, args.role)
            print(f"{said}; {_served(path, 'at their next request')}")
        else:
            said = store.set_password(args.name, _password(args.password_file))
            print(f"{said}; {_served(path, 'at once: their open sessions end')}")
        return 0
    except BrokenPipeError:
        raise
    except (UserError, OSError) as exc:
        print(" ".join(f"shadowless rig user: {exc}".split()), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("shadowless rig user: interrupted; nothing was changed", file=sys.stderr)
        return 130
