"""Zenoh access control generated from a spec: who may send what to whom.

Every node, router and tool session of a cluster runs the same ``access_control`` block
(Zenoh checks it on the receiving side of each link, so every process configures it; a
router's ACL does not protect peers that link to each other directly). Default: deny.
Subjects are the identities authenticated on a link: the user name of user/password
authentication, or the common name of the peer's TLS certificate.

- **node N** may send: puts on ``data/*/N`` (its own samples only), ``args/*/N/**`` (the
  args its measures write, e.g. ``calib/N/nav``), ``sync/**`` and ``sim/**``; liveliness
  tokens ``alive/N``, ``alive/N/**`` and ``sync/*/host/N``; queries for seqs, args, sync
  and the read-only control verbs (``status``, ``args``, ``store``); replies on ``seq/**``,
  ``args/**``, ``sync/**`` and its own ``ctl/N/*``; queryables on ``ctl/N/*``, ``seq/**``,
  ``args/**`` and ``sync/**``; subscriptions anywhere in the cluster.
- **routers** and the **operator** (``hera up``'s launcher, ``hera status/inject/down``,
  the console) may send anything: routers forward the others' messages, which their first
  hop has already checked; the operator is who runs the cluster.
- Anything else, and anyone else, is refused.

So a node's own credentials let it neither publish as another node, nor write an arg of
another node, nor stop, start or crash anything (README "Threat model").
"""

from __future__ import annotations

from typing import Any

OPERATOR = "operator"
"""The identity of the tools and launchers that run a cluster."""

ALL_MESSAGES = [
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "reply",
    "declare_queryable",
    "liveliness_token",
    "liveliness_query",
    "declare_liveliness_subscriber",
]
READ_VERBS = ("status", "args", "store")
"""Control verbs that change nothing: any identity of the cluster may ask them (a tool
reaching the cluster through one node asks the others through it)."""


def _rule(rid: str, messages: list[str], keys: list[str], flows=("ingress",)) -> dict:
    return {
        "id": rid,
        "messages": messages,
        "flows": list(flows),
        "permission": "allow",
        "key_exprs": keys,
    }


def access_control(cluster: str, nodes: list[str], trusted: list[str], tls: bool) -> dict[str, Any]:
    """The ``access_control`` block of cluster ``cluster`` (see the module docstring):
    ``nodes`` get a node's rights, ``trusted`` (routers, the operator) every right."""
    p = f"hera/{cluster}"
    field = "cert_common_names" if tls else "usernames"
    everyone = [*nodes, *trusted]
    rules = [
        _rule("egress", ALL_MESSAGES, ["**"], flows=("egress",)),
        _rule("trusted", ALL_MESSAGES, ["**"]),
        _rule(
            "shared",
            ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"],
            [f"{p}/**"],
        ),
        _rule(
            "shared_queries",
            ["query"],
            [
                f"{p}/seq/**",
                f"{p}/args/**",
                f"{p}/sync/**",
                f"{p}/sim/**",
                *(f"{p}/ctl/*/{verb}" for verb in READ_VERBS),
                f"{p}/launcher/*/status",
            ],
        ),
        _rule("shared_writes", ["put"], [f"{p}/sync/**", f"{p}/sim/**"]),
        _rule("shared_replies", ["reply"], [f"{p}/seq/**", f"{p}/args/**", f"{p}/sync/**"]),
        _rule(
            "shared_queryables",
            ["declare_queryable"],
            [f"{p}/seq/**", f"{p}/args/**", f"{p}/sync/**"],
        ),
    ]
    subjects = [{"id": "everyone", field: everyone}]
    policies = [
        {"id": "egress", "rules": ["egress"], "subjects": ["everyone"]},
        {
            "id": "nodes",
            "rules": [
                "shared",
                "shared_queries",
                "shared_writes",
                "shared_replies",
                "shared_queryables",
            ],
            "subjects": ["everyone"],
        },
    ]
    if trusted:
        subjects.append({"id": "trusted", field: list(trusted)})
        policies.append({"id": "trusted", "rules": ["trusted"], "subjects": ["trusted"]})
    for n in nodes:
        rules += [
            _rule(f"put_{n}", ["put"], [f"{p}/data/*/{n}", f"{p}/args/*/{n}/**"]),
            _rule(
                f"token_{n}",
                ["liveliness_token"],
                [f"{p}/alive/{n}", f"{p}/alive/{n}/**", f"{p}/sync/*/host/{n}"],
            ),
            _rule(f"ctl_{n}", ["reply", "declare_queryable"], [f"{p}/ctl/{n}/*"]),
        ]
        subjects.append({"id": f"node_{n}", field: [n]})
        policies.append(
            {
                "id": f"node_{n}",
                "rules": [f"put_{n}", f"token_{n}", f"ctl_{n}"],
                "subjects": [f"node_{n}"],
            }
        )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }
