"""ROS 2: everything that speaks to a ROS robot, over the memory, the agent and the planner.

- `msgs`: ROS messages <-> what ravenmem stores (images, poses, TF samples), plain dicts <->
  messages and CDR bytes; `tf`: pose tracks through a TF tree;
- `bag`: ROS 1/2 bags and MCAP files as a recording (`ingest` knows it as the `rosbag` source);
- `nav2`: Nav2 map_server maps (YAML + PGM) in and out;
- `link`: the robot link's logic without transport (frames in, goals out); `zenoh`: it over
  Zenoh, with the memory's services;
- `node`: `ravenmem ros run`, an rclpy node (`params` its ROS parameters, `intake` frames into the
  one writer, `outputs` diagnostics and markers, `navigate` NavigateToPose, `ask_action` the
  question action, `convert` messages <-> dicts); `build`: `ravenmem ros setup`;
- `services`: `ravenmem_msgs/srv/Ask` and `Search` (the interface files are in `ravenmem_msgs/`,
  a ROS 2 package a user can `colcon build`); `action`: a NavigateToPose client.

Goals come from `ravenmem.nav.goals.goal_for`, always in the memory's own frame. Importing this
package imports none of its modules; `zenoh` needs the `robot` extra, `node` the `ros` extra
(or a ROS 2 distribution) and `ravenmem ros setup`.
"""
