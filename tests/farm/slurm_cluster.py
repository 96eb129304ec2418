"""A throw-away single-node Slurm cluster on this machine for tests (Debian's slurm-wlm + munge):
its own munge key and munged, a slurm.conf with state, spool, logs, pid files and the munge
socket in a temporary directory, free TCP ports, slurmctld + slurmd. Nothing under /etc or /run
is touched, so it can run beside a real cluster or another test's. Stopped by its pid files.

    with SlurmCluster() as cl:           # needs root (slurmd runs jobs as their users)
        subprocess.run(["sbatch", ...], env=cl.env)
"""
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time

CONF = """\
ClusterName=proden{tag}
SlurmctldHost={host}(127.0.0.1)
SlurmctldPort={ctld_port}
SlurmdPort={d_port}
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket={munge_socket}
SlurmUser=root
SlurmdUser=root
StateSaveLocation={root}/state
SlurmdSpoolDir={root}/spool
SlurmctldPidFile={root}/slurmctld.pid
SlurmdPidFile={root}/slurmd.pid
SlurmctldLogFile={root}/log/slurmctld.log
SlurmdLogFile={root}/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
MpiDefault=none
ReturnToService=2
SchedulerType=sched/backfill
SchedulerParameters=sched_interval=2
MinJobAge=600
KillWait=5
NodeName={host} NodeAddr=127.0.0.1 CPUs={cpus} State=UNKNOWN
PartitionName=proden Nodes={host} Default=YES MaxTime=INFINITE State=UP
"""


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _pid(path):
    try:
        with open(path) as f:
            return int(f.read().strip())
    except (OSError, ValueError):
        return None


def _alive(pid):
    try:
        os.kill(pid, 0)
        return True
    except OSError:
        return False


class SlurmCluster:
    def __init__(self, cpus=2, keep=False):
        if os.geteuid() != 0:
            raise RuntimeError("the test Slurm cluster needs root (slurmd, munged)")
        for exe in ("munged", "slurmctld", "slurmd", "sbatch", "squeue", "scancel", "sinfo"):
            if not shutil.which(exe) and not os.path.exists("/usr/sbin/" + exe):
                raise RuntimeError("%s not installed (tools/install-deps.sh installs slurm-wlm "
                                   "and munge)" % exe)
        self.cpus = cpus
        self.keep = keep
        self.root = None
        self.env = None

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.stop()

    def start(self):
        self.root = tempfile.mkdtemp(prefix="proden-slurm-")
        os.chmod(self.root, 0o711)  # munged wants every parent of its socket traversable
        for d in ("munge", "state", "spool", "log"):
            os.makedirs(os.path.join(self.root, d), mode=0o755)
        key = os.path.join(self.root, "munge", "munge.key")
        with open(key, "wb") as f:
            f.write(os.urandom(1024))
        os.chmod(key, 0o400)
        self.munge_socket = os.path.join(self.root, "munge", "munge.socket")
        self.munge_pid = os.path.join(self.root, "munge", "munged.pid")
        subprocess.run(["/usr/sbin/munged", "--key-file=" + key, "--socket=" + self.munge_socket,
                        "--pid-file=" + self.munge_pid,
                        "--log-file=" + os.path.join(self.root, "log", "munged.log"),
                        "--seed-file=" + os.path.join(self.root, "munge", "seed")],
                       check=True, capture_output=True)
        self.host = socket.gethostname().split(".")[0]
        self.conf = os.path.join(self.root, "slurm.conf")
        with open(self.conf, "w") as f:
            f.write(CONF.format(tag=os.getpid(), host=self.host, ctld_port=free_port(),
                                d_port=free_port(), munge_socket=self.munge_socket,
                                root=self.root, cpus=self.cpus))
        self.env = dict(os.environ, SLURM_CONF=self.conf)
        self.env.pop("SLURM_JOB_ID", None)
        subprocess.run(["/usr/sbin/slurmctld", "-f", self.conf], check=True, env=self.env,
                       capture_output=True)
        subprocess.run(["/usr/sbin/slurmd", "-f", self.conf], check=True, env=self.env,
                       capture_output=True)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            r = subprocess.run(["sinfo", "-h", "-o", "%T"], env=self.env, capture_output=True,
                               text=True)
            if r.returncode == 0 and r.stdout.strip() in ("idle", "mixed", "allocated"):
                return
            time.sleep(0.5)
        log = self.read_logs()
        self.stop()
        raise RuntimeError("the test Slurm node did not come up:\n" + log)

    def run(self, *args, check=True):
        """Runs a Slurm client command against this cluster; returns its stdout."""
        r = subprocess.run(list(args), env=self.env, capture_output=True, text=True)
        if check and r.returncode != 0:
            raise RuntimeError("%s failed: %s" % (" ".join(args), r.stderr.strip()))
        return r.stdout

    def tasks(self, job_id):
        """{task index: state} of an array's tasks still known to slurmctld (MinJobAge keeps
        finished ones for 10 minutes): PENDING, RUNNING, COMPLETED, CANCELLED, FAILED...
        Tasks never started stay folded in the array's own record; once all of them are
        cancelled that record loses their indices (its ArrayTaskId becomes NO_VAL): its state is
        then under the key None."""
        out = self.run("scontrol", "-o", "show", "job", str(job_id), check=False)
        states = {}
        for line in out.split("\n"):
            f = dict(kv.split("=", 1) for kv in line.split() if "=" in kv)
            if f.get("ArrayTaskId") == "4294967294":  # NO_VAL: the folded, now empty record
                states[None] = f.get("JobState")
            elif f.get("ArrayTaskId", "").isdigit():
                states[int(f["ArrayTaskId"])] = f.get("JobState")
            elif "ArrayTaskId" in f:  # a pending range, e.g. 4-11 or 4-11%2
                rng = f["ArrayTaskId"].split("%")[0]
                for part in rng.split(","):
                    lo, _, hi = part.partition("-")
                    for t in range(int(lo), int(hi or lo) + 1):
                        states[t] = f.get("JobState")
        return states

    def wait_empty(self, timeout=300):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if not self.run("squeue", "-h", "-o", "%i", check=False).strip():
                return True
            time.sleep(1)
        return False

    def read_logs(self):
        out = []
        for n in ("slurmctld.log", "slurmd.log", "munged.log"):
            p = os.path.join(self.root or "", "log", n)
            if os.path.exists(p):
                with open(p, errors="replace") as f:
                    out.append("== %s\n%s" % (n, f.read()[-3000:]))
        return "\n".join(out)

    def stop(self):
        if not self.root:
            return
        if self.env:
            subprocess.run(["scancel", "--full", "-u", "root"], env=self.env, capture_output=True)
            self.wait_empty(30)
        for name in ("slurmd.pid", "slurmctld.pid", os.path.join("munge", "munged.pid")):
            pid = _pid(os.path.join(self.root, name))
            if not pid:
                continue
            try:
                os.kill(pid, signal.SIGTERM)
            except OSError:
                continue
            deadline = time.monotonic() + 15
            while _alive(pid) and time.monotonic() < deadline:
                time.sleep(0.1)
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
        if not self.keep:
            shutil.rmtree(self.root, ignore_errors=True)
        self.root = None
