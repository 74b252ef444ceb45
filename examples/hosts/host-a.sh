#!/bin/sh
# Host A of a two-host lab: the lab itself (router, adapter, tdgen, the lights), its router listening on
# every interface so that other hosts can join, its HTTP adapter too. Run on host A, until Ctrl-C:
#
#   sh examples/hosts/host-a.sh                # more `twinmesh up` options may follow, e.g. --no-view
#
# Anyone who reaches host A's port 7447 can drive every Thing: on a shared network, add --secure (see the
# README's "Security and other hosts") or keep the port behind a firewall.
set -eu
exec twinmesh --listen tcp/0.0.0.0:7447 up lights --http 0.0.0.0:8080 "$@"
