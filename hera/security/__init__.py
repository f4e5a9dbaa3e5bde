"""Security of a Hera cluster: who may join the bus, and what each identity may send.

- :mod:`hera.security.secret`: the cluster secret and the passwords derived from it;
- :mod:`hera.security.certs`: ``hera certs``, a cluster CA and one certificate per node,
  router and the operator;
- :mod:`hera.security.access`: the Zenoh access control generated from a spec;
- :mod:`hera.security.credentials`: a process's identity and the Zenoh settings that
  prove it (user/password or mutual TLS), applied to its bus configuration.

README "Threat model" says what this protects against and what it does not.
"""
