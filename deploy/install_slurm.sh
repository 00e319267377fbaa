#!/usr/bin/env bash
# `make slurm`: what tests/integration/test_slurm.py runs a real Slurm cluster with, from
# Debian's registry: slurm-wlm (slurmctld, slurmd, the client commands), slurmdbd and
# mariadb-server (accounting, for sacct) and munge (authentication). As root with apt-get, the
# missing ones are installed (about a minute on a fresh bookworm machine); otherwise it says
# why not and succeeds, and the test prints "SKIPPED: <reason>". Nothing is started or
# enabled here: the test starts its own daemons in network namespaces and stops them.
set -euo pipefail

BINARIES=(slurmctld slurmd slurmdbd sbatch sacct munged mariadbd mariadb-install-db)
PACKAGES=(slurm-wlm slurmdbd munge mariadb-server mariadb-client)
say() { echo "make slurm: $*"; }
source "$(dirname "${BASH_SOURCE[0]}")/apt_lib.sh"

missing=()
for b in "${BINARIES[@]}"; do
    PATH=$PATH:/usr/sbin:/sbin command -v "$b" > /dev/null || missing+=("$b")
done
if [ ${#missing[@]} -eq 0 ]; then
    say "slurm-wlm, slurmdbd, munge and mariadb-server are installed"
    exit 0
fi
install_or_skip "${missing[*]}" "install ${PACKAGES[*]} to run the Slurm test" \
    "install Slurm, slurmdbd, munge and MariaDB"
say "installing ${PACKAGES[*]} (missing: ${missing[*]})"
# policy-rc.d exit 101: the packages' post-install scripts start no daemon
policy=/usr/sbin/policy-rc.d
made_policy=""
if [ ! -e "$policy" ]; then
    printf '#!/bin/sh\nexit 101\n' > "$policy" && chmod +x "$policy" && made_policy=1
fi
trap '[ -n "$made_policy" ] && rm -f "$policy"' EXIT
apt_install "${PACKAGES[@]}"
say "installed"
