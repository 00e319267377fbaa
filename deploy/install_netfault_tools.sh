#!/usr/bin/env bash
# `make netfault-tools`: what tests/fault/test_network_faults.py and bench/faults/net_faults.py
# make a network between namespaced hosts with, from Debian's registry: iproute2 (`ip` for namespaces
# and veth links, `tc` for the tbf rate limit) and iptables (random loss with the `statistic`
# match, cuts with DROP). As root with apt-get, the missing ones are installed (seconds);
# otherwise it says why not and succeeds, and the test prints "SKIPPED: <reason>". Nothing is
# configured here: the test makes its own namespaces, chains and qdiscs and removes them.
set -euo pipefail

say() { echo "make netfault-tools: $*"; }
source "$(dirname "${BASH_SOURCE[0]}")/apt_lib.sh"

export PATH=$PATH:/usr/sbin:/sbin
packages=()
{ command -v ip && command -v tc; } > /dev/null || packages+=(iproute2)
command -v iptables > /dev/null || packages+=(iptables)
if [ ${#packages[@]} -eq 0 ]; then
    say "iproute2 (ip, tc) and iptables are installed"
    exit 0
fi
install_or_skip "${packages[*]}" "install them to run the network-fault test"
say "installing ${packages[*]}"
apt_install "${packages[@]}"
say "installed"
