# lib.sh - process helpers shared by slurm_up.sh and slurm_down.sh (sourced; needs log, die,
# CONF and LAB_DIR defined by the caller).
# shellcheck shell=bash

pidfile_pid() { if [ -s "$1" ]; then tr -dc '0-9' <"$1"; fi; }

# proc_field PID N - Nth field of /proc/PID/stat counted after "(comm)":
# 1 = state, 2 = ppid, 3 = pgrp.  Empty if the process is gone.
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

# pid_alive PID [COMM] - exists, is not a zombie (PID 1 of a container may be
# slow to reap) and, if COMM is given, /proc/PID/comm is COMM (so a recycled
# pid from a stale pid file is never taken for our daemon).
pid_alive() {
    local pid=${1:-} comm=${2:-}
    [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null || return 1
    [ "$(proc_field "$pid" 1)" != Z ] || return 1
    [ -z "$comm" ] || [ "$(cat "/proc/$pid/comm" 2>/dev/null || true)" = "$comm" ]
}

# stop_pid NAME PID - SIGTERM, wait up to 20 s, then SIGKILL and wait 5 s.
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

# kill_job_leftovers - after a crash, slurmstepd processes of *this* cluster
# (they inherit SLURM_CONF=$CONF from our slurmd) and the job processes under
# them survive; slurmstepd ignores SIGTERM, so SIGKILL their process groups.
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
