"""Zenoh security for several machines: mutual TLS, user/password, and access control by identity.

Each process of the stack is one *identity* (``learner``, ``robot-io``, ``vision``, ``monitor``,
``supervisor``, ``router``): the common name of its certificate and its Zenoh user name. The identity
comes from the process, not the config file, so one file serves every machine: ``adaptiveh <part>``
sets it from the command (``IDENTITY_ENV`` overrides, ``adaptiveh up`` sets it per part), and paths and
the user name may contain ``{identity}`` (``certs/test/{identity}.pem``).

The router enforces who may do what (``access_control: roles``, Zenoh's ACL with default deny): every
authenticated identity may subscribe, query liveliness and receive everything under ``adaptiveh/``, but
puts only on the keys its part owns (:data:`ROLES`): only the learner on ``cmd/**`` (robot-io's own
report ``cmd/status`` excepted), only the monitor on ``control``. Anything else a session puts is
dropped at the router; a session without a certificate of our CA or without the right password cannot
connect at all. ``scripts/make_test_certs.sh`` makes test certificates and passwords.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, Field, model_validator

from bus import messages as m
from common.config import ConfigError, Section

IDENTITY_ENV = "ADAPTIVEH_ZENOH_IDENTITY"
PLACEHOLDER = "{identity}"
Identity = str

#: ``adaptiveh <command>`` -> the identity its session has unless ``IDENTITY_ENV`` says otherwise.
COMMAND_IDENTITY: dict[str, Identity] = {
    "robot-io": "robot-io",
    "vision": "vision",
    "monitor": "monitor",
    "learn": "learner",
    "act": "actor",
    "router": "router",
    "up": "supervisor",
}
#: ``adaptiveh up``'s part names -> identities.
PART_IDENTITY: dict[str, Identity] = {
    "robot_io": "robot-io",
    "vision": "vision",
    "monitor": "monitor",
    "learner": "learner",
    "actor": "actor",
}

# What each identity may send into the router, as keys below ``adaptiveh/<robot>/`` (any robot). The
# liveliness names are the parts' ``alive_as`` (``alive/<name>`` and anything below it).
_ALIVE = m.LIVELINESS
ROLES: dict[Identity, dict[str, tuple[str, ...]]] = {
    "learner": {
        "put": (
            "cmd/**",
            m.EVENTS_RETREAT.name,
            m.TELEMETRY_LEARNER.name,
            m.POLICY.name,
            m.TRANSITION_ACKS.name,
        ),
        "query": (m.RESET.name,),
        "liveliness_token": (f"{_ALIVE}/learner/**",),
    },
    "actor": {  # beside the arm: commands it as a learner session does, streams what it played
        "put": ("cmd/**", m.TRANSITIONS.name, m.EVENTS_SAFETY.name),
        "query": (m.RESET.name,),
        "liveliness_token": (f"{_ALIVE}/learner/**", f"{_ALIVE}/actor/**"),
    },
    "robot-io": {
        "put": (m.STATE.name, m.CHUNK_STATUS.name, m.EVENTS_SAFETY.name, "sim/**"),
        "declare_queryable": (m.RESET.name,),
        "reply": (m.RESET.name,),
        "liveliness_token": (f"{_ALIVE}/robot_io/**",),
    },
    "vision": {
        "put": (m.TARGET.name, "camera/**", m.EVENTS_SAFETY.name),
        "liveliness_token": (f"{_ALIVE}/vision/**",),
    },
    "monitor": {
        "put": (m.CONTROL.name,),
        "liveliness_token": (f"{_ALIVE}/monitor/**",),
    },
}
#: Denials inside a role's own allowance (Zenoh: a matching deny beats any allow).
DENIED: dict[Identity, dict[str, tuple[str, ...]]] = {
    "learner": {"put": (m.CHUNK_STATUS.name,)},
    "actor": {"put": (m.CHUNK_STATUS.name,)},
}
_READ = ("declare_subscriber", "declare_liveliness_subscriber", "liveliness_query")
_ALL = (
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
)


_MAKE = "test certificates: scripts/make_test_certs.sh"


def _resolve(template: str, identity: str, key: str) -> str:
    if PLACEHOLDER not in template:
        return template
    if not identity:
        raise ConfigError(
            f"{key}: {template!r} needs this process's identity: set {IDENTITY_ENV} (learner, robot-io, ...)"
        )
    return template.replace(PLACEHOLDER, identity)


def _must_exist(path: str, key: str, identity: str = "") -> str:
    if not Path(path).is_file():
        who = f" (identity {identity})" if identity else ""
        raise ConfigError(f"{key}: no such file {path}{who}; {_MAKE}")
    return path


def _static_file(path: str) -> str:
    """At load: a path without ``{identity}`` must exist; with it, its folder must ("": not set)."""
    if not path:
        return path
    if PLACEHOLDER in path:
        folder = Path(path.split(PLACEHOLDER, 1)[0] + "x").parent
        if not folder.is_dir():
            raise ValueError(f"no such folder {folder} (for {path}); {_MAKE}")
    elif not Path(path).is_file():
        raise ValueError(f"no such file {path}; {_MAKE}")
    return path


FilePath = Annotated[str, AfterValidator(_static_file)]
"""A file the config names, checked at load; ``{identity}`` in it is resolved when the session opens."""


class TlsConfig(Section):
    """``zenoh.tls``: the CA every session trusts and this identity's certificate (for listening and
    connecting alike). Use ``tls/host:port`` endpoints."""

    ca: FilePath  # the CA certificate (PEM) that signed every identity's certificate
    cert: FilePath = Field(
        "certs/test/{identity}.pem",
        description="this identity's certificate (PEM), signed by ca; {identity} is replaced by the"
        " process's identity (learner, robot-io, ...)",
    )
    key: FilePath = Field(
        "certs/test/{identity}.key", description="the private key (PEM) of cert; {identity} as in cert"
    )
    # A listener (the router) accepts only clients with a certificate of ``ca``: mutual TLS. Access control
    # by identity needs it (the client's common name is its identity).
    mtls: bool = True
    verify_name: bool = True  # a client checks the router's certificate names the host it dialled


class AuthConfig(Section):
    """``zenoh.auth``: Zenoh user/password. The password is read from a file (mode 0600) or an
    environment variable, never from the config or a command line."""

    user: str = Field(
        "{identity}",
        min_length=1,
        description="the Zenoh user name; {identity} is replaced by the process's identity, so each part"
        " logs in as its own user",
    )
    # A file holding the password (mode 0600), e.g. certs/test/{identity}.password; or password_env.
    password_file: FilePath = ""
    # The name of the environment variable holding the password; or password_file.
    password_env: str = Field("", pattern=r"^([A-Za-z_][A-Za-z0-9_]*)?$")

    @model_validator(mode="after")
    def _one_password_source(self) -> AuthConfig:
        if bool(self.password_file) == bool(self.password_env):
            raise ValueError("set exactly one of password_file and password_env")
        return self

    def credentials(self, identity: str) -> tuple[str, str]:
        """(user, password) of ``identity``; a ConfigError naming the key if the password is missing."""
        user = _resolve(self.user, identity, "zenoh.auth.user")
        if self.password_env:
            password = os.environ.get(self.password_env, "")
            if not password:
                raise ConfigError(f"zenoh.auth.password_env: ${self.password_env} is not set or empty")
            return user, password
        key = "zenoh.auth.password_file"
        path = _must_exist(_resolve(self.password_file, identity, key), key, identity)
        mode = os.stat(path).st_mode
        if mode & 0o077:
            raise ConfigError(
                f"zenoh.auth.password_file: {path} is readable by others (mode {oct(stat.S_IMODE(mode))});"
                " chmod 600 it"
            )
        password = Path(path).read_text().strip()
        if not password:
            raise ConfigError(f"zenoh.auth.password_file: {path} is empty")
        return user, password


class RouterConfig(Section):
    """``zenoh.router``: read only by ``adaptiveh router --config`` (a session in router mode)."""

    listen: tuple[str, ...] = ()  # e.g. [tls/0.0.0.0:7447]; --listen overrides
    dictionary_file: str = ""  # user:password per line, for zenoh.auth (only the router machine has it)
    # roles: Zenoh's ACL with default deny, each identity puts only on its part's keys (bus.security);
    # none: any session that authenticates may put anything (not "off": YAML reads that as false).
    access_control: Literal["roles", "none"] = "roles"


def check_router(cfg: Any) -> None:
    """What ``access_control: roles`` needs to tell identities apart; raises ValueError naming the key."""
    router = cfg.router
    if router is None:
        return
    identified = (cfg.tls is not None and cfg.tls.mtls) or cfg.auth is not None
    if router.access_control == "roles" and not identified:
        raise ValueError(
            "router.access_control: roles tells identities apart by certificate (zenoh.tls with mtls: true)"
            " or by user (zenoh.auth); configure one, or set access_control: none"
        )
    by_user_only = router.access_control == "roles" and not (cfg.tls is not None and cfg.tls.mtls)
    if by_user_only and PLACEHOLDER not in cfg.auth.user:  # one user for all: every identity alike
        raise ValueError(
            f"router.access_control: roles by user name needs zenoh.auth.user to contain {PLACEHOLDER}"
        )
    if cfg.auth is not None and not router.dictionary_file:
        raise ValueError("router.dictionary_file: with zenoh.auth the router needs the user:password file")


def subjects(identity: str, tls: TlsConfig | None, auth: AuthConfig | None) -> dict[str, Any]:
    """The ACL subject of ``identity``: its certificate's common name and/or its user name."""
    subject: dict[str, Any] = {"id": identity}
    if tls is not None and tls.mtls:
        subject["cert_common_names"] = [identity]
    if auth is not None:
        subject["usernames"] = [auth.user.replace(PLACEHOLDER, identity)]
    return subject


def _rule(
    rule_id: str, messages: tuple[str, ...], flow: str, key_exprs: list[str], permission: str = "allow"
) -> dict[str, Any]:
    return {
        "id": rule_id,
        "messages": list(messages),
        "flows": [flow],
        "permission": permission,
        "key_exprs": key_exprs,
    }


def access_control(tls: TlsConfig | None, auth: AuthConfig | None) -> dict[str, Any]:
    """Zenoh's ``access_control`` section for ``roles``: default deny, reads for all, puts by role."""

    if not ((tls is not None and tls.mtls) or auth is not None):  # a subject without either matches anyone
        raise ValueError("access control by identity needs zenoh.tls with mtls or zenoh.auth")

    def keys(rel: tuple[str, ...]) -> list[str]:  # a stack's keys, and an arm's of a fleet
        return [f"{m.NAMESPACE}/{owner}/{k}" for k in rel for owner in ("*", "*/*")]

    everything = [f"{m.NAMESPACE}/**"]
    rules: list[dict[str, Any]] = [
        _rule("read", _READ, "ingress", everything),  # any identity that got in may subscribe, watch alive
        _rule("deliver", _ALL, "egress", everything),  # and is sent whatever the router accepted from others
        _rule("relay", _ALL, "ingress", everything),  # another router relays everything it accepted
    ]
    policies = [
        {"id": "everyone", "rules": ["read", "deliver"], "subjects": ["anyone"]},
        {"id": "router", "rules": ["relay"], "subjects": ["router"]},
    ]
    for identity, role in ROLES.items():
        ids = []
        for message, rel in role.items():
            ids.append(f"{identity}-{message}")
            rules.append(_rule(ids[-1], (message,), "ingress", keys(rel)))
        for message, rel in DENIED.get(identity, {}).items():
            ids.append(f"{identity}-no-{message}")
            rules.append(_rule(ids[-1], (message,), "ingress", keys(rel), "deny"))
        policies.append({"id": identity, "rules": ids, "subjects": [identity]})
    named = [subjects(identity, tls, auth) for identity in [*ROLES, "router"]]
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": [{"id": "anyone"}, *named],
        "policies": policies,
    }


def zenoh_keys(cfg: Any, identity: str) -> dict[str, Any]:
    """The Zenoh config keys for ``cfg``'s tls/auth (and router, in router mode) as ``identity``.

    Files named by ``{identity}`` are resolved and checked here: a ConfigError names the key.
    """
    out: dict[str, Any] = {}
    if cfg.tls is not None:
        t = cfg.tls
        cert = _must_exist(_resolve(t.cert, identity, "zenoh.tls.cert"), "zenoh.tls.cert", identity)
        key = _must_exist(_resolve(t.key, identity, "zenoh.tls.key"), "zenoh.tls.key", identity)
        tls = {
            "root_ca_certificate": _must_exist(t.ca, "zenoh.tls.ca"),
            "listen_certificate": cert,
            "listen_private_key": key,
            "connect_certificate": cert,
            "connect_private_key": key,
            "enable_mtls": t.mtls,
            "verify_name_on_connect": t.verify_name,
        }
        out.update({f"transport/link/tls/{k}": v for k, v in tls.items()})
    if cfg.auth is not None:
        user, password = cfg.auth.credentials(identity)
        out["transport/auth/usrpwd/user"] = user
        out["transport/auth/usrpwd/password"] = password
    if cfg.mode == "router" and cfg.router is not None:
        if cfg.router.dictionary_file:
            out["transport/auth/usrpwd/dictionary_file"] = _must_exist(
                cfg.router.dictionary_file, "zenoh.router.dictionary_file"
            )
        if cfg.router.access_control == "roles":
            out["access_control"] = access_control(cfg.tls, cfg.auth)
    return out


_command_identity = ""


def set_command_identity(command: str) -> None:
    """Called by the CLI: ``adaptiveh <command>``'s default identity (``COMMAND_IDENTITY``), for this
    process only (not inherited: ``adaptiveh up`` gives each part its own through ``IDENTITY_ENV``)."""
    global _command_identity
    _command_identity = COMMAND_IDENTITY.get(command, "")


def process_identity() -> str:
    """This process's identity: ``$ADAPTIVEH_ZENOH_IDENTITY``, else its command's, else ""."""
    return os.environ.get(IDENTITY_ENV, "") or _command_identity
