# Runs COMMAND (a ;-list) and checks its exit code is EXIT (0 or "nonzero") and that its
# combined output matches the regular expression EXPECT. Used for tests of the `prism` binary
# where both the exit code and the message matter.
execute_process(COMMAND ${COMMAND} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
set(all "${out}${err}")
if(EXIT STREQUAL "nonzero")
  if(rc EQUAL 0)
    message(FATAL_ERROR "expected a non-zero exit, got 0; output:\n${all}")
  endif()
elseif(NOT rc EQUAL EXIT)
  message(FATAL_ERROR "expected exit ${EXIT}, got ${rc}; output:\n${all}")
endif()
if(NOT all MATCHES "${EXPECT}")
  message(FATAL_ERROR "output does not match '${EXPECT}':\n${all}")
endif()
