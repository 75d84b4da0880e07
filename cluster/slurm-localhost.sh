#!/usr/bin/env bash
# A single-node SLURM cluster on this machine, to run the workflow through the SLURM executor
# exactly as on a real cluster (profiles/slurm).
#
#   cluster/slurm-localhost.sh start    install (apt-get) if missing, configure, start, wait until idle
#   cluster/slurm-localhost.sh stop     stop the daemons this script started
#   cluster/slurm-localhost.sh status   daemons, node and partition state
#
# Debian/Ubuntu with apt-get; needs root (re-runs itself through sudo when it is available).
# No systemd needed: munged, slurmctld and slurmd are started directly, with pid files.
# `start` is idempotent: a running cluster with the same configuration is left alone; a changed
# one (other cores or memory) is restarted.
#
# The node is sized from this machine: CPUs = nproc, RealMemory = `free -m` total minus 5 %
# (at least 512 MB) so slurmd never finds less memory than configured and drains the node.
# Job status: no accounting database (AccountingStorageType=accounting_storage/none), so sacct
# cannot answer; the profile sets `slurm-status-command: squeue`, and MinJobAge keeps finished
# jobs visible to squeue for 30 minutes.
#
# Environment (all optional):
#   CVSFLOW_SLURM_STATE   state dir: spool, job state, pid files, logs [/var/tmp/cvsflow-slurm]
#   CVSFLOW_SLURM_CPUS    CPUs of the node [nproc]
#   CVSFLOW_SLURM_MEM_MB  RealMemory of the node in MB [free -m total minus 5 %]
#   CVSFLOW_SLURM_WAIT_S  seconds to wait for the node to become idle [120]
set -euo pipefail

STATE=${CVSFLOW_SLURM_STATE:-/var/tmp/cvsflow-slurm}
CONF=/etc/slurm/slurm.conf
MARK="# cvsflow single-node cluster: written by cluster/slurm-localhost.sh"
WAIT_S=${CVSFLOW_SLURM_WAIT_S:-120}
PARTITION=local
MUNGE_PID=/run/munge/munged.pid

log() { printf '[slurm-localhost] %s\n' "$*" >&2; }
die() { log "error: $*"; exit 1; }

if [[ $EUID -ne 0 ]]; then
    command -v sudo >/dev/null || die "needs root (apt-get, /etc/slurm, daemons) and sudo is missing"
    exec sudo --preserve-env=CVSFLOW_SLURM_STATE,CVSFLOW_SLURM_CPUS,CVSFLOW_SLURM_MEM_MB,CVSFLOW_SLURM_WAIT_S \
        "$0" "$@"
fi

alive() { [[ -s $1 ]] && kill -0 "$(cat "$1")" 2>/dev/null; }

install_packages() {
    local missing=()
    command -v munged >/dev/null || missing+=(munge)
    command -v slurmctld >/dev/null || missing+=(slurmctld)
    command -v slurmd >/dev/null || missing+=(slurmd)
    command -v sinfo >/dev/null || missing+=(slurm-client)
    [[ ${#missing[@]} -eq 0 ]] && return
    log "installing ${missing[*]} (apt-get)"
    export DEBIAN_FRONTEND=noninteractive
    # slurm-wlm pulls in the daemons and the client; the names are listed for clarity.
    local pkgs=(slurm-wlm slurmctld slurmd slurm-client munge)
    if ! apt-get install -y -q --no-install-recommends "${pkgs[@]}" >>"$STATE/log/apt.log" 2>&1; then
        apt-get update -q >>"$STATE/log/apt.log" 2>&1
        apt-get install -y -q --no-install-recommends "${pkgs[@]}" >>"$STATE/log/apt.log" 2>&1 \
            || die "apt-get install failed, see $STATE/log/apt.log"
    fi
}

node_name() { hostname -s; }

write_conf() {  # the wanted slurm.conf on stdout
    local cpus mem_total mem node
    cpus=${CVSFLOW_SLURM_CPUS:-$(nproc)}
    mem_total=$(free -m | awk '/^Mem:/ {print $2}')
    mem=${CVSFLOW_SLURM_MEM_MB:-$(( mem_total - (mem_total / 20 > 512 ? mem_total / 20 : 512) ))}
    node=$(node_name)
    cat <<EOF
$MARK
# Node sized from this machine: nproc=$(nproc), free -m total=${mem_total}.
ClusterName=cvsflow
SlurmctldHost=${node}(127.0.0.1)
AuthType=auth/munge
CredType=cred/munge
# Root runs everything: no slurm user, no cgroups (works in containers and VMs without systemd).
SlurmUser=root
SlurmdUser=root
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MpiDefault=none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
# The CPUs and memory below win over what slurmd detects (nproc can be less than the hardware).
SlurmdParameters=config_overrides
# A node that was down (daemon restart) comes back by itself once slurmd registers.
ReturnToService=2
# Finished jobs stay visible to squeue for 30 min: the executor reads job states from squeue.
MinJobAge=1800
SlurmctldTimeout=30
SlurmdTimeout=60
InactiveLimit=0
KillWait=10
StateSaveLocation=$STATE/ctld
SlurmdSpoolDir=$STATE/d
SlurmctldPidFile=$STATE/slurmctld.pid
SlurmdPidFile=$STATE/slurmd.pid
SlurmctldLogFile=$STATE/log/slurmctld.log
SlurmdLogFile=$STATE/log/slurmd.log
SlurmctldPort=6817
SlurmdPort=6818
NodeName=${node} NodeAddr=127.0.0.1 CPUs=${cpus} RealMemory=${mem} State=UNKNOWN
PartitionName=${PARTITION} Nodes=${node} Default=YES MaxTime=INFINITE State=UP
EOF
}

start_munge() {
    if munge -n </dev/null 2>/dev/null | unmunge >/dev/null 2>&1; then
        return  # a munged already answers (ours from an earlier start, or the machine's own)
    fi
    if [[ ! -s /etc/munge/munge.key ]]; then
        log "creating /etc/munge/munge.key"
        mungekey --create --keyfile=/etc/munge/munge.key
        chown munge:munge /etc/munge/munge.key
        chmod 0400 /etc/munge/munge.key
    fi
    install -d -o munge -g munge -m 0755 /run/munge
    install -d -o munge -g munge -m 0700 /var/lib/munge /var/log/munge
    log "starting munged"
    runuser -u munge -- /usr/sbin/munged --pid-file="$MUNGE_PID" \
        --log-file=/var/log/munge/munged.log
    for _ in $(seq 50); do
        munge -n </dev/null 2>/dev/null | unmunge >/dev/null 2>&1 && return
        sleep 0.1
    done
    die "munged does not answer, see /var/log/munge/munged.log"
}

stop_pidfile() {  # stop_pidfile NAME PIDFILE
    local name=$1 pidfile=$2 pid
    alive "$pidfile" || { rm -f "$pidfile"; return 0; }
    pid=$(cat "$pidfile")
    log "stopping $name (pid $pid)"
    kill "$pid"
    for _ in $(seq 100); do
        kill -0 "$pid" 2>/dev/null || { rm -f "$pidfile"; return 0; }
        sleep 0.1
    done
    log "$name did not stop in 10 s, killing it"
    kill -9 "$pid" 2>/dev/null || true
    rm -f "$pidfile"
}

stop_slurm() {
    stop_pidfile slurmd "$STATE/slurmd.pid"
    stop_pidfile slurmctld "$STATE/slurmctld.pid"
}

node_state() { sinfo -h -N -n "$(node_name)" -o %T 2>/dev/null | head -1; }

wait_idle() {
    local t0=$SECONDS state=""
    while (( SECONDS - t0 < WAIT_S )); do
        state=$(node_state || true)
        case $state in
            idle|mixed|allocated) log "node $(node_name) is $state"; return 0 ;;
            *drain*|down*|fail*)
                scontrol update nodename="$(node_name)" state=resume 2>/dev/null || true ;;
        esac
        sleep 0.5
    done
    die "node not idle after ${WAIT_S}s (state '${state}'); see $STATE/log/slurm{ctld,d}.log"
}

cmd_start() {
    local t0=$SECONDS
    mkdir -p "$STATE/log" "$STATE/ctld" "$STATE/d"
    install_packages
    if [[ -e $CONF ]] && ! grep -qxF "$MARK" "$CONF"; then
        die "$CONF exists and was not written by this script: this machine has its own SLURM; use it"
    fi
    local want
    want=$(write_conf)
    if [[ ! -e $CONF ]] || [[ "$want" != "$(cat "$CONF")" ]]; then
        if alive "$STATE/slurmctld.pid" || alive "$STATE/slurmd.pid"; then
            log "configuration changed: restarting"
            stop_slurm
        fi
        mkdir -p /etc/slurm
        printf '%s\n' "$want" >"$CONF"
        log "wrote $CONF ($(grep -o 'CPUs=[0-9]* RealMemory=[0-9]*' "$CONF"))"
    fi
    start_munge
    if ! alive "$STATE/slurmctld.pid"; then
        log "starting slurmctld (log $STATE/log/slurmctld.log)"
        slurmctld -i
    fi
    if ! alive "$STATE/slurmd.pid"; then
        log "starting slurmd (log $STATE/log/slurmd.log)"
        slurmd
    fi
    wait_idle
    log "ready in $(( SECONDS - t0 )) s: partition '$PARTITION', $(sinfo -h -o '%c CPUs, %m MB' | head -1)"
}

cmd_stop() {
    stop_slurm
    stop_pidfile munged "$MUNGE_PID"
}

cmd_status() {
    local rc=0 name pidfile
    for name in munged slurmctld slurmd; do
        case $name in
            munged) pidfile=$MUNGE_PID ;;
            *) pidfile=$STATE/$name.pid ;;
        esac
        if alive "$pidfile"; then
            echo "$name: running (pid $(cat "$pidfile"))"
        else
            echo "$name: stopped"; rc=1
        fi
    done
    if (( rc == 0 )); then
        sinfo -N -o '%N %P %T %c %m' || rc=1
    fi
    echo "state dir: $STATE"
    return $rc
}

case ${1:-} in
    start) cmd_start ;;
    stop) cmd_stop ;;
    status) cmd_status ;;
    *) echo "usage: $0 start|stop|status" >&2; exit 2 ;;
esac
