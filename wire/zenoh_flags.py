"""zenoh endpoint, TLS and login flags shared by ``swarmseek sensor``, ``mock``, ``watch`` and ``run``.

:func:`add_endpoint_arguments` adds ``--zenoh-listen`` / ``--zenoh-connect`` (each command words
their help for its own role); :func:`add_arguments` adds ``--zenoh-tls-ca``, ``--zenoh-tls-cert``,
``--zenoh-tls-key``, ``--zenoh-mtls``, ``--zenoh-user`` and ``--zenoh-password-file`` (the
password is never on the command line; a world-readable password file is refused).
:func:`security_kwargs` checks the combination against the endpoints and returns the keyword
arguments of :func:`wire.zenoh_config.zenoh_config`: the certificate and key become ``listen_*``
for ``tls/`` listen endpoints and ``connect_*`` for ``tls/`` connect endpoints. The password file
is read by :func:`wire.zenoh_secrets.read_password_file`, as the plan's ``[zenoh.auth]`` one is.
:func:`plain_network_warning` is the warning ``ctl``, ``watch``, ``sensor`` and ``mock`` print when
an endpoint another machine can reach is not TLS (:mod:`wire.loopback`'s rule).
"""
from __future__ import annotations

import argparse
from pathlib import Path

from wire.cli_args import path_problem, zenoh_endpoint
from wire.loopback import IsLoopback, host_is_loopback, network_endpoints
from wire.zenoh_secrets import ZenohSecurityError, read_password_file

__all__ = ["ZenohFlagError", "add_arguments", "add_endpoint_arguments", "plain_network_warning", "security_kwargs"]


class ZenohFlagError(ValueError):
    """The zenoh security flags are inconsistent or a secret file is unusable."""


def _existing_file(text: str) -> str:
    problem = path_problem(text)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    if not Path(text).is_file():
        raise argparse.ArgumentTypeError(f"file not found: {text}")
    return text


def _password_file_arg(text: str) -> str:
    _existing_file(text)
    try:
        read_password_file(text)  # check now (argparse error); read again when used
    except ZenohSecurityError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def add_endpoint_arguments(parser: argparse.ArgumentParser, *, listen_help: str | None = None,
                           connect_help: str | None = None, connect_first: bool = False) -> None:
    """Add the repeatable ``--zenoh-listen`` and ``--zenoh-connect`` (a list of checked endpoints,
    empty by default); an option whose help is None is not added."""
    options = [("--zenoh-listen", listen_help), ("--zenoh-connect", connect_help)]
    for flag, help_text in (options[::-1] if connect_first else options):
        if help_text is not None:
            parser.add_argument(flag, type=zenoh_endpoint, action="append", default=[], metavar="ENDPOINT",
                                help=help_text)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the zenoh TLS / login flags to ``parser`` (next to ``--zenoh-listen/--zenoh-connect``)."""
    parser.add_argument("--zenoh-tls-ca", type=_existing_file, default=None, metavar="PATH",
                        help="CA certificate (PEM) that signed the peers' TLS certificates")
    parser.add_argument("--zenoh-tls-cert", type=_existing_file, default=None, metavar="PATH",
                        help="this session's TLS certificate (PEM), used on tls/ endpoints")
    parser.add_argument("--zenoh-tls-key", type=_existing_file, default=None, metavar="PATH",
                        help="private key (PEM) of --zenoh-tls-cert")
    parser.add_argument("--zenoh-mtls", action="store_true",
                        help="mutual TLS: present the certificate and require the peer's")
    parser.add_argument("--zenoh-user", default=None, metavar="NAME",
                        help="zenoh user name (with --zenoh-password-file)")
    parser.add_argument("--zenoh-password-file", type=_password_file_arg, default=None, metavar="PATH",
                        help="file whose first line is the zenoh password (not world-readable)")


def _is_tls(endpoint: str) -> bool:
    return endpoint.startswith(("tls/", "quic/"))


def security_kwargs(args: argparse.Namespace) -> dict:
    """Check the zenoh security flags and return the matching ``zenoh_config`` keywords.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed flags of :func:`add_arguments` plus ``zenoh_listen`` and ``zenoh_connect``.

    Returns
    -------
    dict
        Some of ``tls`` (mapping of ``transport/link/tls`` file keys), ``enable_mtls``,
        ``username`` and ``password``; empty when no security flag was given.

    Raises
    ------
    ZenohFlagError
        A certificate without its key (or the reverse), TLS flags without a ``tls/`` endpoint,
        a ``tls/`` listen endpoint without certificate, ``--zenoh-mtls`` without CA, certificate
        and key, a user without a password file (or the reverse), or an unusable password file.
    """
    listen_tls = any(_is_tls(ep) for ep in args.zenoh_listen or ())
    connect_tls = any(_is_tls(ep) for ep in args.zenoh_connect or ())
    ca, cert, key = args.zenoh_tls_ca, args.zenoh_tls_cert, args.zenoh_tls_key
    if (cert is None) != (key is None):
        raise ZenohFlagError("--zenoh-tls-cert and --zenoh-tls-key go together (a certificate needs its key)")
    if (ca or cert or args.zenoh_mtls) and not (listen_tls or connect_tls):
        raise ZenohFlagError("zenoh TLS flags given but no tls/ endpoint "
                             "(use e.g. --zenoh-connect tls/127.0.0.1:7447)")
    if listen_tls and cert is None:
        raise ZenohFlagError("a tls/ listen endpoint needs --zenoh-tls-cert and --zenoh-tls-key")
    if args.zenoh_mtls and (ca is None or cert is None):
        raise ZenohFlagError("--zenoh-mtls needs --zenoh-tls-ca, --zenoh-tls-cert and --zenoh-tls-key")
    out: dict = {}
    tls: dict = {}
    if ca is not None:
        tls["root_ca_certificate"] = ca
    if cert is not None:
        for side, used in (("listen", listen_tls), ("connect", connect_tls)):
            if used:
                tls[f"{side}_certificate"], tls[f"{side}_private_key"] = cert, key
    if tls:
        out["tls"] = tls
    if args.zenoh_mtls:
        out["enable_mtls"] = True
    if (args.zenoh_user is None) != (args.zenoh_password_file is None):
        raise ZenohFlagError("--zenoh-user and --zenoh-password-file go together")
    if args.zenoh_user is not None:
        if not args.zenoh_user or ":" in args.zenoh_user:
            raise ZenohFlagError(f"--zenoh-user must be a non-empty name without ':', got {args.zenoh_user!r}")
        out["username"] = args.zenoh_user
        try:
            out["password"] = read_password_file(args.zenoh_password_file)
        except ZenohSecurityError as exc:
            raise ZenohFlagError(f"--zenoh-password-file: {exc}") from None
    return out


def plain_network_warning(prog: str, listen, connect, is_loopback: IsLoopback = host_is_loopback) -> str | None:
    """The one-line warning for zenoh endpoints another machine can reach without TLS, or None.

    Parameters
    ----------
    prog : str
        The command (``"swarmseek ctl"``), first on the line.
    listen, connect : iterable of str or None
        The session's endpoints.
    is_loopback : callable
        ``host -> bool`` (default :func:`wire.loopback.host_is_loopback`).

    Returns
    -------
    str or None
        ``"PROG: warning: ..."`` naming the plain (not ``tls/``) network endpoints; None when every
        network endpoint is TLS or every endpoint is loopback.
    """
    plain = [ep for ep in network_endpoints(list(listen or ()) + list(connect or ()), is_loopback)
             if not _is_tls(ep)]
    if not plain:
        return None
    return (f"{prog}: warning: {', '.join(plain)} is not loopback and not TLS: anyone on the network path "
            f"can read what this session sends and receives (commands, readings, the mission state) and "
            f"pose as its peer; use tls/ endpoints with --zenoh-tls-ca (docs/security.md)")
