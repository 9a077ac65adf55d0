#!/usr/bin/env bash
# slurm_up.sh - bring up a private single-node Slurm cluster on this host (used by the
# job-array test in tests/it/batch.rs; also handy to try examples/slurm/ by hand).
#
# Target: Debian 12 (bookworm), run as root, no systemd needed (works in
# containers / gVisor).  Idempotent: if the cluster is already up (node idle,
# mixed or allocated) it only says so; a crashed or half-started cluster from
# an earlier run is cleaned up and restarted.
#
# Everything Slurm writes lives under $SLURM_LAB_DIR (default /tmp/slurm-local):
#   etc/slurm.conf  state/  spool/  log/  run/
# The system munged (/run/munge/munge.socket.2, /etc/munge/munge.key) is used;
# it is started here if it is not already answering.
#
# On success the last line on stdout is   SLURM_CONF=<path to slurm.conf>
# (all progress messages go to stderr) and $SLURM_LAB_DIR/env holds
# "export SLURM_CONF=...".  Clients (sbatch, sinfo, ...) need SLURM_CONF in
# their environment unless /etc/slurm/slurm.conf was free and got symlinked
# to ours (SLURM_LAB_LINK_ETC=1, the default).
#
# Tunables (environment):
#   SLURM_LAB_DIR        private directory                          [/tmp/slurm-local]
#   SLURM_UP_TIMEOUT     seconds allowed for each wait              [60]
#   SLURM_CLUSTER_NAME   ClusterName                                [localtest]
#   SLURM_PARTITION      name of the (Default=YES) partition        [debug]
#   SLURM_CTLD_PORT      SlurmctldPort                              [6817]
#   SLURM_SLURMD_PORT    SlurmdPort                                 [6818]
#   SLURM_MIN_JOB_AGE    MinJobAge; <=5 makes `sbatch --wait` poll every 2 s
#                        but finished jobs vanish from squeue/scontrol after
#                        that many seconds                          [300]
#   SLURM_EXTRA_CONF     extra lines appended to slurm.conf         []
#   SLURM_LAB_LINK_ETC   1 = symlink /etc/slurm/slurm.conf if free  [1]
#   SLURM_SKIP_APT       1 = never run apt-get                      [0]
set -euo pipefail

LAB_DIR=${SLURM_LAB_DIR:-/tmp/slurm-local}
LAB_DIR=${LAB_DIR%/}
TIMEOUT=${SLURM_UP_TIMEOUT:-60}
CLUSTER=${SLURM_CLUSTER_NAME:-localtest}
PARTITION=${SLURM_PARTITION:-debug}
CTLD_PORT=${SLURM_CTLD_PORT:-6817}
SLURMD_PORT=${SLURM_SLURMD_PORT:-6818}
MIN_JOB_AGE=${SLURM_MIN_JOB_AGE:-300}
EXTRA_CONF=${SLURM_EXTRA_CONF:-}
LINK_ETC=${SLURM_LAB_LINK_ETC:-1}
SKIP_APT=${SLURM_SKIP_APT:-0}

CONF=$LAB_DIR/etc/slurm.conf
ETC_CONF=/etc/slurm/slurm.conf
MUNGE_SOCKET=/run/munge/munge.socket.2
MUNGE_PIDFILE=/run/munge/munged.pid
MUNGE_KEY=/etc/munge/munge.key
# What is really needed: slurm-wlm is only a metapackage over these three
# slurm packages; slurm-wlm-basic-plugins (+ liblua5.1-0) and munge come in
# as dependencies.  Recommends (slurm-wlm-plugins: ipmi, rrd, hdf5, ...) are
# not needed.
PKGS="slurmctld slurmd slurm-client munge"

log() { echo "slurm_up: $*" >&2; }
die() { echo "slurm_up: ERROR: $*" >&2; exit 1; }
show_logs() {
    local f
    for f in "$LAB_DIR/log/slurmctld.log" "$LAB_DIR/log/slurmd.log" /var/log/munge/munged.log; do
        [ -f "$f" ] || continue
        echo "----- last lines of $f -----" >&2
        tail -n 25 "$f" >&2 || true
    done
}
die_logs() { echo "slurm_up: ERROR: $*" >&2; show_logs; exit 1; }

[ "$(id -u)" -eq 0 ] || die "must be run as root (it installs packages and starts daemons)"
case "$LAB_DIR" in
    /|/tmp|/var|/var/tmp|/root|/home|/etc|/usr|/run) die "SLURM_LAB_DIR=$LAB_DIR is too broad: use a private directory" ;;
    /*) ;;
    *) die "SLURM_LAB_DIR must be an absolute path (got '$LAB_DIR')" ;;
esac
for v in TIMEOUT CTLD_PORT SLURMD_PORT MIN_JOB_AGE; do
    case "${!v}" in ''|*[!0-9]*) die "$v must be a number (got '${!v}')" ;; esac
done

# wait_until SECONDS CMD...  -> 0 as soon as CMD succeeds, 1 on timeout
wait_until() {
    local limit=$1; shift
    local deadline=$((SECONDS + limit))
    until "$@" >/dev/null 2>&1; do
        [ "$SECONDS" -lt "$deadline" ] || return 1
        sleep 0.5
    done
}

# Process helpers (pid files, liveness, stopping, leftover job processes).
# shellcheck source=tests/slurm/lib.sh
. "$(dirname "$0")/lib.sh"

mkdir -p "$LAB_DIR"
# Serialise concurrent callers (e.g. parallel tests).  The lock lives beside
# LAB_DIR (slurm_down.sh deletes LAB_DIR) and fd 9 is closed for every daemon.
exec 9>"$LAB_DIR.lock"
flock -w "$TIMEOUT" 9 || die "another slurm_up/slurm_down holds $LAB_DIR.lock for more than ${TIMEOUT}s"

# --------------------------------------------------------------------------
# 1. packages
# --------------------------------------------------------------------------
missing=""
for p in $PKGS; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' \
        || missing="$missing $p"
done
if [ -n "$missing" ]; then
    [ "$SKIP_APT" != 1 ] || die "packages missing:$missing (and SLURM_SKIP_APT=1)"
    log "installing:$missing"
    export DEBIAN_FRONTEND=noninteractive
    # Keep the packages' maintainer scripts from starting munge, slurmd and
    # slurmctld through invoke-rc.d: there is no systemd, and we start them
    # ourselves with our own config below.
    policy_added=0
    if [ ! -e /usr/sbin/policy-rc.d ]; then
        printf '#!/bin/sh\nexit 101\n' >/usr/sbin/policy-rc.d
        chmod 0755 /usr/sbin/policy-rc.d
        policy_added=1
        trap 'rm -f /usr/sbin/policy-rc.d' EXIT
    fi
    apt-get -o DPkg::Lock::Timeout=300 -qq update >&2 \
        || die "apt-get update failed"
    # shellcheck disable=SC2086
    apt-get -o DPkg::Lock::Timeout=300 -y -q --no-install-recommends install $missing >&2 \
        || die "apt-get install failed for:$missing"
    if [ "$policy_added" = 1 ]; then rm -f /usr/sbin/policy-rc.d; trap - EXIT; fi
    log "packages installed after ${SECONDS}s"
fi
for b in munged munge unmunge slurmctld slurmd sinfo sbatch scontrol flock; do
    command -v "$b" >/dev/null 2>&1 || die "'$b' not found on PATH (packages: $PKGS)"
done

# --------------------------------------------------------------------------
# 2. munge: key + daemon (the system instance, run as user munge like the
#    systemd unit does)
# --------------------------------------------------------------------------
munge_ok() { munge -n -S "$MUNGE_SOCKET" 2>/dev/null | unmunge -S "$MUNGE_SOCKET" >/dev/null 2>&1; }

id munge >/dev/null 2>&1 || die "user 'munge' does not exist (munge package broken?)"
if [ ! -s "$MUNGE_KEY" ]; then
    log "creating munge key $MUNGE_KEY"
    install -d -o munge -g munge -m 0700 "$(dirname "$MUNGE_KEY")"
    if command -v mungekey >/dev/null 2>&1; then
        mungekey --create --keyfile="$MUNGE_KEY" --force
    else
        dd if=/dev/urandom of="$MUNGE_KEY" bs=1024 count=1 status=none
    fi
fi
# munged refuses a key that is readable by others or not owned by its user.
chown munge:munge "$MUNGE_KEY"
chmod 0400 "$MUNGE_KEY"

mpid=$(pidfile_pid "$MUNGE_PIDFILE")
if [ -S "$MUNGE_SOCKET" ] && { [ -z "$mpid" ] || pid_alive "$mpid" munged; } && munge_ok; then
    log "munged already running"
else
    # /run is a tmpfs: nothing recreates the runtime dir systemd would make
    # (RuntimeDirectory=munge, mode 0755, owned by munge).
    install -d -o munge -g munge -m 0755 /run/munge
    install -d -o munge -g munge -m 0700 /var/log/munge
    install -d -o munge -g munge -m 0711 /var/lib/munge
    if pid_alive "$mpid" munged; then
        log "munged (pid $mpid) is not answering; restarting it"
        stop_pid munged "$mpid"
    fi
    rm -f "$MUNGE_PIDFILE"
    log "starting munged"
    # It daemonizes itself.  --force: take over a stale socket left by a
    # munged that was SIGKILLed.
    runuser -u munge -- /usr/sbin/munged --force </dev/null >/dev/null 2>&1 9>&- \
        || die_logs "munged failed to start"
    touch "$LAB_DIR/munged.started-by-slurm_up"     # slurm_down.sh stops it then
    wait_until "$TIMEOUT" munge_ok \
        || die_logs "munged does not answer on $MUNGE_SOCKET after ${TIMEOUT}s"
fi

# --------------------------------------------------------------------------
# 3. already up?  (idempotency)
# --------------------------------------------------------------------------
NODE=$(hostname -s)
[ -n "$NODE" ] || die "'hostname -s' printed nothing"

node_state() { SLURM_CONF=$CONF timeout 10 sinfo -h -N -n "$NODE" -o '%T' 2>/dev/null | head -n1; }
ctld_alive() { pid_alive "$(pidfile_pid "$LAB_DIR/run/slurmctld.pid")" slurmctld; }
slurmd_alive() { pid_alive "$(pidfile_pid "$LAB_DIR/run/slurmd.pid")" slurmd; }

if [ -f "$CONF" ] && ctld_alive && slurmd_alive; then
    state=$(node_state)
    case "$state" in
        idle|mixed|allocated|completing)
            log "cluster already up (node $NODE $state), nothing to do"
            echo "SLURM_CONF=$CONF"
            exit 0 ;;
    esac
    log "daemons running but node is '${state:-<no answer>}': restarting the cluster"
fi

# Whatever is left of an earlier run is stopped and its state wiped.
stop_pid slurmd "$(pidfile_pid "$LAB_DIR/run/slurmd.pid")"
stop_pid slurmctld "$(pidfile_pid "$LAB_DIR/run/slurmctld.pid")"
kill_job_leftovers
rm -rf "${LAB_DIR:?}/etc" "$LAB_DIR/state" "$LAB_DIR/spool" "$LAB_DIR/run" "$LAB_DIR/log"
mkdir -p "$LAB_DIR/etc" "$LAB_DIR/state" "$LAB_DIR/spool" "$LAB_DIR/run" "$LAB_DIR/log"
chmod 0755 "$LAB_DIR" "$LAB_DIR/etc"

# --------------------------------------------------------------------------
# 4. slurm.conf
# --------------------------------------------------------------------------
# `slurmd -C` prints this machine's real layout, e.g.
#   NodeName=vm CPUs=2 Boards=1 SocketsPerBoard=1 CoresPerSocket=2 ThreadsPerCore=1 RealMemory=24105
# Re-using it verbatim keeps the configured CPUs/sockets/cores/memory equal to
# what slurmd registers, so the node is not DRAINed for "Low RealMemory" or
# "Low socket*core*thread count".
hw=$(slurmd -C 2>/dev/null | grep '^NodeName=' | head -n1 || true)
[ -n "$hw" ] || die "'slurmd -C' printed no NodeName= line"
hw=${hw#NodeName=* }        # keep "CPUs=... RealMemory=..."
case "$hw" in *CPUs=*RealMemory=*) ;; *) die "unexpected 'slurmd -C' output: $hw" ;; esac

cat >"$CONF" <<EOF
# Generated by slurm_up.sh: single-node test cluster.  Do not edit.
ClusterName=$CLUSTER
# The name must be \`hostname -s\`; the address avoids any DNS/hosts lookup.
SlurmctldHost=$NODE(127.0.0.1)
SlurmctldPort=$CTLD_PORT
SlurmdPort=$SLURMD_PORT
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$MUNGE_SOCKET

StateSaveLocation=$LAB_DIR/state
SlurmdSpoolDir=$LAB_DIR/spool
SlurmctldPidFile=$LAB_DIR/run/slurmctld.pid
SlurmdPidFile=$LAB_DIR/run/slurmd.pid
SlurmctldLogFile=$LAB_DIR/log/slurmctld.log
SlurmdLogFile=$LAB_DIR/log/slurmd.log
SlurmctldDebug=info
SlurmdDebug=info

# No cgroups anywhere (container/gVisor, no systemd): no cgroup.conf needed.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MpiDefault=none
SwitchType=switch/none
MailProg=/bin/true

SchedulerType=sched/backfill
# Default 3 s: the 3rd array task (2 cores here) would wait 3 s for a slot.
SchedulerParameters=batch_sched_delay=0
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ReturnToService=2
MinJobAge=$MIN_JOB_AGE
SlurmdTimeout=300
InactiveLimit=0
KillWait=5

NodeName=$NODE NodeAddr=127.0.0.1 NodeHostname=$NODE $hw State=UNKNOWN
PartitionName=$PARTITION Nodes=$NODE Default=YES MaxTime=INFINITE State=UP
EOF
if [ -n "$EXTRA_CONF" ]; then
    printf '# from SLURM_EXTRA_CONF\n%s\n' "$EXTRA_CONF" >>"$CONF"
fi

echo "export SLURM_CONF=$CONF" >"$LAB_DIR/env"

if [ "$LINK_ETC" = 1 ]; then
    if [ ! -e "$ETC_CONF" ] && [ ! -L "$ETC_CONF" ]; then
        mkdir -p "$(dirname "$ETC_CONF")"
        ln -s "$CONF" "$ETC_CONF"
        log "linked $ETC_CONF -> $CONF"
    elif [ "$(readlink "$ETC_CONF" 2>/dev/null || true)" != "$CONF" ]; then
        log "note: $ETC_CONF exists and is not ours; clients need SLURM_CONF=$CONF"
    fi
fi
# slurmd passes this on to slurmstepd and the jobs (slurm_down.sh relies on it).
export SLURM_CONF=$CONF

# --------------------------------------------------------------------------
# 5. start the daemons (they daemonize, write their pid files and detach
#    from our stdio, so a caller reading our stdout is not kept waiting)
# --------------------------------------------------------------------------
log "starting slurmctld"
slurmctld -f "$CONF" </dev/null >>"$LAB_DIR/log/slurmctld.stdout" 2>&1 9>&- \
    || die_logs "slurmctld failed to start"
wait_until "$TIMEOUT" sh -c 'scontrol ping | grep -q "is UP"' \
    || die_logs "slurmctld does not answer 'scontrol ping' after ${TIMEOUT}s (port $CTLD_PORT taken?)"

log "starting slurmd"
slurmd -f "$CONF" -N "$NODE" </dev/null >>"$LAB_DIR/log/slurmd.stdout" 2>&1 9>&- \
    || die_logs "slurmd failed to start"

# --------------------------------------------------------------------------
# 6. wait for the node to be idle
# --------------------------------------------------------------------------
log "waiting (up to ${TIMEOUT}s) for node $NODE to become idle"
t0=$SECONDS
state=""
while :; do
    state=$(node_state)
    case "$state" in
        idle) break ;;
        *drain*|*down*|*fail*|*inval*)
            # A node whose registration is rejected (e.g. CPU or memory
            # mismatch) shows up like this; allow 10 s before failing.
            if [ $((SECONDS - t0)) -ge 10 ]; then
                scontrol show node "$NODE" >&2 || true
                die_logs "node $NODE is '$state' (reason: $(sinfo -h -R -n "$NODE" -o '%E' 2>/dev/null || true))"
            fi ;;
    esac
    ctld_alive || die_logs "slurmctld died"
    slurmd_alive || die_logs "slurmd died (port $SLURMD_PORT taken?)"
    if [ $((SECONDS - t0)) -ge "$TIMEOUT" ]; then
        scontrol show node "$NODE" >&2 || true
        die_logs "node $NODE still '${state:-<no answer>}' after ${TIMEOUT}s (expected idle)"
    fi
    sleep 0.5
done

log "cluster '$CLUSTER' up in ${SECONDS}s: node $NODE idle, partition $PARTITION; export SLURM_CONF=$CONF"
echo "SLURM_CONF=$CONF"
