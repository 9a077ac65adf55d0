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

pidfile_pid() { if [ -s "$1" ]; then tr -dc '0-9' <"$1"; fi; }

# proc_field PID N - Nth field of /proc/PID/stat after "(comm)": 1 state, 2 ppid, 3 pgrp
proc_field() {
    local s n=$2
    s=$(cat "/proc/$1/stat" 2>/dev/null) || return 0
    s=${s##*) }
    set -f
    # shellcheck disable=SC2086
    set -- $s
    set +f
    eval "echo \${$n:-}"
}

# pid_alive PID [COMM] - exists, not a zombie, and /proc comm is COMM if given
pid_alive() {
    local pid=${1:-} comm=${2:-}
    [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null || return 1
    [ "$(proc_field "$pid" 1)" != Z ] || return 1
    [ -z "$comm" ] || [ "$(cat "/proc/$pid/comm" 2>/dev/null || true)" = "$comm" ]
}

# stop_pid NAME PID - SIGTERM, wait up to 20 s, then SIGKILL and wait 5 s.
# Only a live process whose comm is NAME is touched (stale pid files).
stop_pid() {
    local name=$1 pid=${2:-}
    pid_alive "$pid" "$name" || return 0
    log "stopping $name (pid $pid)"
    kill -TERM "$pid" 2>/dev/null || true
    for _ in $(seq 1 40); do pid_alive "$pid" || return 0; sleep 0.5; done
    log "$name (pid $pid) ignored SIGTERM for 20s; sending SIGKILL"
    kill -KILL "$pid" 2>/dev/null || true
    for _ in $(seq 1 10); do pid_alive "$pid" || return 0; sleep 0.5; done
    die "$name (pid $pid) is still alive after SIGKILL"
}

# kill_job_leftovers - slurmstepd processes of *this* cluster (they inherit
# SLURM_CONF=$CONF from our slurmd) and the job processes under them survive
# a dead slurmd; slurmstepd ignores SIGTERM, so SIGKILL their process groups.
kill_job_leftovers() {
    local f pid p pg victims="" groups=""
    for f in /proc/[0-9]*/environ; do
        pid=${f#/proc/}; pid=${pid%/environ}
        pid_alive "$pid" slurmstepd || continue
        { tr '\0' '\n' <"$f"; } 2>/dev/null | grep -qxF "SLURM_CONF=$CONF" || continue
        victims="$victims $pid"
    done
    # job scripts whose slurmstepd is already gone: /bin/sh $LAB_DIR/spool/jobNNNNN/slurm_script
    for f in /proc/[0-9]*/cmdline; do
        pid=${f#/proc/}; pid=${pid%/cmdline}
        { tr '\0' ' ' <"$f"; } 2>/dev/null | grep -qF "$LAB_DIR/spool/job" || continue
        pg=$(proc_field "$pid" 3)
        [ -n "$pg" ] && [ "$pg" -gt 1 ] && case " $groups " in *" $pg "*) ;; *) groups="$groups $pg" ;; esac
    done
    # descendants of the slurmstepds (job steps run in their own process groups)
    if [ -n "$victims" ]; then
        for f in /proc/[0-9]*/stat; do
            pid=${f#/proc/}; pid=${pid%/stat}
            p=$(proc_field "$pid" 2)
            case " $victims " in *" $p "*)
                pg=$(proc_field "$pid" 3)
                [ -n "$pg" ] && [ "$pg" -gt 1 ] && case " $groups " in *" $pg "*) ;; *) groups="$groups $pg" ;; esac ;;
            esac
        done
    fi
    [ -n "$victims$groups" ] || return 0
    log "killing leftover job processes of this cluster:${victims}${groups:+ (process groups$groups)}"
    for pg in $groups; do kill -KILL -- "-$pg" 2>/dev/null || true; done
    for pid in $victims; do kill -KILL "$pid" 2>/dev/null || true; done
    sleep 0.5
}

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
