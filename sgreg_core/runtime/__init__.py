"""What an sgreg agent decides at run time, free of ROS: the agent's own graph and features
(agent.py), the wire encoding of features (wire.py), and the per-peer registration state machine
(peers.py). The ROS nodes in sgreg_ros are thin shells over these."""
