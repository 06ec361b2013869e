# The ROS 1 layer. Built only when catkin and the ROS packages are found (Debian's ROS 1:
# ros_comm 1.15); -DNERFSLAM_BUILD_ROS=OFF forces it off. The library never includes ROS headers but
# src/io/bag/dataset_bag.cpp's (bags read without ROS, CMakeLists.txt); every node lives under apps/ros/.
set(NERFSLAM_ROS_COMPONENTS roscpp std_msgs std_srvs sensor_msgs geometry_msgs nav_msgs visualization_msgs
    tf2 tf2_ros tf2_geometry_msgs image_transport cv_bridge pcl_conversions diagnostic_updater)
find_package(catkin QUIET COMPONENTS ${NERFSLAM_ROS_COMPONENTS} message_generation)
if(NOT catkin_FOUND)
  message(STATUS "nerfslam: catkin / ROS packages not found, building without the ROS layer")
  return()
endif()
message(STATUS "nerfslam: building the ROS layer (catkin ${catkin_VERSION})")
# Our messages (msg/): the off-board mapping link between tracking_node and nerf_mapping_node
# (docs/ros.md). C++ headers go to <devel>/include/nerfslam/*.h (target nerfslam_generate_messages_cpp).
add_message_files(DIRECTORY msg FILES MapKeyframe.msg KeyframePoses.msg)
generate_messages(DEPENDENCIES std_msgs sensor_msgs geometry_msgs)
catkin_package(
  INCLUDE_DIRS include
  LIBRARIES ${NERFSLAM_MODULES}
  CATKIN_DEPENDS ${NERFSLAM_ROS_COMPONENTS} message_runtime)
if(EXISTS ${PROJECT_SOURCE_DIR}/apps/ros/CMakeLists.txt)
  add_subdirectory(apps/ros)
endif()
