# Sourced by the install scripts that add Debian packages to a test machine where they are
# missing (install_browser.sh, install_netfault_tools.sh, install_slurm.sh,
# install_mujoco_py.sh). The sourcing script defines say() first.

# Unless this is root with apt-get, says why nothing is installed and exits 0: a machine
# without the packages still runs everything else, and the test that needs them says SKIPPED.
# $1: what is missing; $2: what to do instead; $3 (optional): what to do instead without
# apt-get, where that differs.
install_or_skip() {
    if [ "$(id -u)" -ne 0 ]; then
        say "SKIPPED: $1 missing and not root: $2"
        exit 0
    fi
    if ! command -v apt-get > /dev/null; then
        say "SKIPPED: $1 missing and no apt-get: ${3:-$2}"
        exit 0
    fi
}

# apt-get install of the packages named, quietly and without recommends.
apt_install() {
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends "$@" > /dev/null
}
