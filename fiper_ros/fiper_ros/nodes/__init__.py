"""ROS 2 node shells of the suite: messages to arrays, the core and runtime modules, arrays to messages."""
