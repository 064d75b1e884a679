"""Ray nodes on this machine on loopback only, as a process of its own (a test and benchmark helper).

``python tests/service/ray_two_nodes.py TEMP_DIR CPUS_PER_NODE [NODES]`` starts a head and NODES - 1 more
nodes (default: two nodes in all), all with node address 127.0.0.1 and Ray's files under TEMP_DIR, and prints one JSON line: the cluster's
address and its node ids. Then it answers one command per line on stdin: ``cpus`` prints the
CPUs free now (``{"CPU": x}``); end of input stops the nodes (only the processes this helper started).

``ray start --node-ip-address 127.0.0.1`` replaces a loopback address by the machine's network
address in Ray 2.60, so the nodes are started through Ray's own test cluster
(``ray.cluster_utils.Cluster``), which takes the address as given.
"""

from __future__ import annotations

import json
import os
import sys


def main() -> None:
    import ray
    from ray.cluster_utils import Cluster

    temp_dir, cpus = sys.argv[1], int(sys.argv[2])
    count = int(sys.argv[3]) if len(sys.argv) > 3 else 2
    os.makedirs(os.path.join(temp_dir, "ray"), exist_ok=True)  # Ray notes the cluster's address there (RAY_TMPDIR)
    node = dict(node_ip_address="127.0.0.1", num_cpus=cpus, object_store_memory=80 * 1024 * 1024)
    cluster = Cluster(initialize_head=True, head_node_args=dict(node, temp_dir=temp_dir, include_dashboard=False))
    try:
        for _ in range(count - 1):
            cluster.add_node(**node)
        cluster.wait_for_nodes()
        ray.init(address=cluster.address, log_to_driver=False)
        nodes = [n["NodeID"] for n in ray.nodes() if n["Alive"]]
        print(json.dumps({"address": cluster.address, "nodes": nodes,
                          "ips": sorted({n["NodeManagerAddress"] for n in ray.nodes()})}), flush=True)
        for line in sys.stdin:
            if line.strip() == "cpus":
                print(json.dumps({"CPU": ray.available_resources().get("CPU", 0.0)}), flush=True)
    finally:
        ray.shutdown()
        cluster.shutdown()


if __name__ == "__main__":
    main()
