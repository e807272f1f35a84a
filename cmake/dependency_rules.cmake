# The layering the code keeps (docs/design.md, "Layers"): services/ (the job layer in
# services/job among them) depends on nothing above it; the worker and the coordinator depend on
# services/ and not on each other, so `prism-worker` links no coordinator code and
# `prism-coordinator` links neither the tracer nor Embree. `prism render` (client/) and the
# in-process LocalRender are where the two meet.
#
# prism_check_link_rules() runs at the end of configuration and fails it when a daemon reaches a
# forbidden library through any chain of target_link_libraries; tests/dependency_rules.cmake
# checks the same rules on the #include lines (ctest: dependency_rules).

# Every library `target` links, directly or through others (ALIAS targets resolved, generator
# expressions such as $<LINK_ONLY:x> unwrapped), appended to the variable named by `out`.
function(prism_collect_links target out)
  set(seen ${${out}})
  set(queue ${target})
  while(queue)
    list(POP_FRONT queue current)
    if(NOT TARGET ${current})
      continue()
    endif()
    get_target_property(aliased ${current} ALIASED_TARGET)
    if(aliased)
      set(current ${aliased})
    endif()
    if(current IN_LIST seen)
      continue()
    endif()
    list(APPEND seen ${current})
    set(links)
    get_target_property(type ${current} TYPE)
    if(NOT type STREQUAL "INTERFACE_LIBRARY")
      get_target_property(direct ${current} LINK_LIBRARIES)
      if(direct)
        list(APPEND links ${direct})
      endif()
    endif()
    get_target_property(interface ${current} INTERFACE_LINK_LIBRARIES)
    if(interface)
      list(APPEND links ${interface})
    endif()
    foreach(link IN LISTS links)
      string(REGEX REPLACE "^\\$<LINK_ONLY:(.*)>$" "\\1" link "${link}")
      if(link MATCHES "^\\$<")
        continue()
      endif()
      list(APPEND queue ${link})
    endforeach()
  endwhile()
  set(${out} ${seen} PARENT_SCOPE)
endfunction()

# FATAL_ERROR when `target` links any of the targets named after it.
function(prism_forbid_links target)
  set(reached)
  prism_collect_links(${target} reached)
  foreach(forbidden IN LISTS ARGN)
    if(TARGET ${forbidden})
      get_target_property(aliased ${forbidden} ALIASED_TARGET)
      if(aliased)
        set(forbidden ${aliased})
      endif()
    endif()
    if(forbidden IN_LIST reached)
      message(FATAL_ERROR
        "${target} links ${forbidden}, which the layering forbids (cmake/dependency_rules.cmake): "
        "move what it needs into services/ (the job layer is services/job).")
    endif()
  endforeach()
endfunction()

function(prism_check_link_rules)
  prism_forbid_links(prism-worker prism_coordinator prism_farm_coordinator prism_local_render)
  prism_forbid_links(prism-coordinator prism_worker prism_worker_daemon prism_local_render embree)
  foreach(service prism_base prism_spectral prism_image prism_scene prism_scene_io prism_store
                  prism_job prism_rpc)
    prism_forbid_links(${service} prism_worker prism_coordinator prism_farm_coordinator)
  endforeach()
endfunction()
