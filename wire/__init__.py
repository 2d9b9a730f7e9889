"""What both ends of a link share: the ground station (``mission``) and the simulated world
(``sitl_mock``) import it, and it imports nothing of the project.

* :mod:`wire.signing` - MAVLink 2 signing key files (hex, raw or passphrase) and timestamps;
* :mod:`wire.fleet_name` - the one rule for fleet names (a zenoh key chunk naming one fleet);
* :mod:`wire.zenoh_config` - a zenoh session configuration with explicit endpoints;
* :mod:`wire.zenoh_secrets` - the password file and user dictionary of zenoh security;
* :mod:`wire.zenoh_flags` - the ``--zenoh-tls-*`` / ``--zenoh-user`` command-line flags;
* :mod:`wire.loopback` - is an address on this machine only (the security checks' rule);
* :mod:`wire.cli_args` - argparse argument types (numbers in ranges, coordinates, paths).
* :mod:`wire.fast_decode` - one whole, valid MAVLink 2 frame decoded into pymavlink's own message
  without pymavlink's byte-stream parser (the ground station's and the mock autopilots' receive path).
"""
