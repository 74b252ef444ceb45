#!/bin/sh
# Host B of a two-host lab: devices of its own (one fleet station: belt-1, infrared-1, color-1, light-1,
# climate-1) joining host A's lab through a gateway on this host. Run on host B, until Ctrl-C:
#
#   LAB_HOST=host-a sh examples/hosts/host-b.sh        # LAB_HOST: host A's name or address
#
# Then, from anywhere that reaches host A:
#   twinmesh --connect tcp/host-a:7447 things            # host A's lights and host B's station
#   curl http://host-a:8080/climate-1/properties/temperature
set -eu
: "${LAB_HOST:?set LAB_HOST to host A's name or address}"
exec twinmesh up fleet --fleet 5 --join "tcp/$LAB_HOST:7447" "$@"
