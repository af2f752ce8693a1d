import os

# Tests never talk to wandb and never compete for more than the machine's cores.
os.environ["WANDB_MODE"] = "disabled"
os.environ.setdefault("OMP_NUM_THREADS", "2")
