#!/usr/bin/env bash
# slurm_down.sh - stop the private cluster started by slurm_up.sh and clean up.
#
# - cancels remaining jobs (while slurmctld is still up),
# - stops slurmd and slurmctld through their pid files under $SLURM_LAB_DIR
#   (never by process name, so other Slurm instances are left alone),
# - SIGKILLs leftover slurmstepd/job processes of this cluster (after a crash),
# - stops munged only if slurm_up.sh started it (SLURM_DOWN_KEEP_MUNGE=1 keeps it),
# - removes /etc/slurm/slurm.conf if it is our symlink,
# - deletes $SLURM_LAB_DIR (SLURM_DOWN_KEEP_DIR=1 keeps it, e.g. for the logs).
#   Only the empty lock file $SLURM_LAB_DIR.lock is left behind.
# Safe to run when nothing is running; packages stay installed.
set -euo pipefail

LAB_DIR=${SLURM_LAB_DIR:-/tmp/slurm-local}
LAB_DIR=${LAB_DIR%/}
KEEP_MUNGE=${SLURM_DOWN_KEEP_MUNGE:-0}
KEEP_DIR=${SLURM_DOWN_KEEP_DIR:-0}
CONF=$LAB_DIR/etc/slurm.conf
ETC_CONF=/etc/slurm/slurm.conf
MUNGE_PIDFILE=/run/munge/munged.pid

log() { echo "slurm_down: $*" >&2; }
die() { echo "slurm_down: ERROR: $*" >&2; exit 1; }

[ "$(id -u)" -eq 0 ] || die "must be run as root"
case "$LAB_DIR" in
    /|/tmp|/var|/var/tmp|/root|/home|/etc|/usr|/run) die "refusing to work on SLURM_LAB_DIR=$LAB_DIR" ;;
    /*) ;;
    *) die "SLURM_LAB_DIR must be an absolute path (got '$LAB_DIR')" ;;
esac

# Process helpers (pid files, liveness, stopping, leftover job processes).
# shellcheck source=tests/slurm/lib.sh
. "$(dirname "$0")/lib.sh"

# Serialise with slurm_up.sh / other callers (fd 9 is closed for daemons).
if [ -d "$LAB_DIR" ] || [ -e "$LAB_DIR.lock" ]; then
    exec 9>"$LAB_DIR.lock"
    flock -w 60 9 || die "another slurm_up/slurm_down holds $LAB_DIR.lock for more than 60s"
fi

# 1. Cancel whatever is still queued/running so that slurmd reaps the steps.
ctld_pid=$(pidfile_pid "$LAB_DIR/run/slurmctld.pid")
if [ -f "$CONF" ] && pid_alive "$ctld_pid" slurmctld && command -v squeue >/dev/null 2>&1; then
    export SLURM_CONF=$CONF
    users=$(timeout 10 squeue -h -o %u 2>/dev/null | sort -u || true)
    if [ -n "$users" ]; then
        log "cancelling remaining jobs"
        for u in $users; do timeout 10 scancel --quiet --user="$u" >/dev/null 2>&1 || true; done
        for _ in $(seq 1 30); do     # up to 15 s for the jobs to go away
            [ -z "$(timeout 10 squeue -h -o %i 2>/dev/null || true)" ] && break
            sleep 0.5
        done
    fi
fi

# 2. Daemons: slurmd first, then the controller.
stop_pid slurmd "$(pidfile_pid "$LAB_DIR/run/slurmd.pid")"
stop_pid slurmctld "$(pidfile_pid "$LAB_DIR/run/slurmctld.pid")"

# 3. Job processes that outlived their slurmd (crash, kill -9, ...).
kill_job_leftovers

# 4. munged, if it is ours.
if [ -e "$LAB_DIR/munged.started-by-slurm_up" ]; then
    if [ "$KEEP_MUNGE" != 1 ]; then
        stop_pid munged "$(pidfile_pid "$MUNGE_PIDFILE")"
    fi
    rm -f "$LAB_DIR/munged.started-by-slurm_up"
fi

# 5. Files.
if [ -L "$ETC_CONF" ] && [ "$(readlink "$ETC_CONF")" = "$CONF" ]; then
    rm -f "$ETC_CONF"
    log "removed symlink $ETC_CONF"
fi
if [ "$KEEP_DIR" != 1 ]; then
    # (the empty $LAB_DIR.lock stays: deleting a lock file others may be
    # waiting on would let two callers in at once)
    rm -rf "${LAB_DIR:?}"
fi
log "done"
