# Every third-party dependency, found once. Versions and reasons: third_party/README.md.
find_package(Threads REQUIRED)
find_package(Eigen3 3.4 REQUIRED NO_MODULE)
find_package(OpenCV 4 REQUIRED COMPONENTS core imgproc imgcodecs features2d calib3d video videoio)
find_package(Ceres 2 REQUIRED)
find_package(yaml-cpp REQUIRED)
find_package(fmt REQUIRED)
find_package(spdlog REQUIRED)
find_package(nlohmann_json 3 REQUIRED)
find_package(CLI11 REQUIRED)
find_package(hwy REQUIRED)
# libjpeg (libjpeg-turbo, the one OpenCV decodes with): corrupt JPEG data is found by decoding with
# an error manager that turns libjpeg's warnings into errors (src/io/jpeg_check.cpp).
find_package(JPEG REQUIRED)
# zlib: a PNG's pixel data is inflated once to check it holds every row (src/io/image_header.cpp).
find_package(ZLIB REQUIRED)
# PCL only for point-cloud/mesh files (PLY/PCD); only the components we use, to keep VTK out.
find_package(PCL 1.10 REQUIRED COMPONENTS common io)
# OctoMap: the 3D occupancy maps' tree, log-odds and .bt/.ot files (src/nerf/voxel_map.cpp).
find_package(octomap 1.9 REQUIRED)
if(TARGET yaml-cpp::yaml-cpp AND NOT TARGET yaml-cpp)
  add_library(yaml-cpp ALIAS yaml-cpp::yaml-cpp)
endif()

# OSMesa: offscreen software OpenGL. It must come before any libGL on the link line, or GL calls
# resolve to a libGL without a context and silently draw nothing.
find_package(PkgConfig REQUIRED)
pkg_check_modules(OSMESA REQUIRED IMPORTED_TARGET osmesa)
add_library(nerfslam_osmesa INTERFACE)
target_link_libraries(nerfslam_osmesa INTERFACE PkgConfig::OSMESA)
