# The tests that take longest under AddressSanitizer, with what each took in seconds (CI of
# 2026-12-05 on 2 cores: `ctest -j2` in build-asan). ctest -j starts the costliest tests first;
# in a clean build tree there is no Testing/Temporary/CTestCostData.txt yet, so without these
# it ran them in declaration order, and the 330-s GUI test, declared near the end, started
# 1.4 minutes before the rest had finished and then ran alone for 4 more (ctest 1,065 s for
# 1,901 s of tests on 2 cores). After one run ctest's own history takes over.
# Included by CMakeLists.txt (add_test's tests) and by each suite's labels script in ctest
# (gtest's discovered tests), which applies the costs of the names in its list.
set(OCTORAY_TEST_COSTS
  viewer_gui 330
  bench_working_set_small 185
  BatchArchiveTest.PlansRunsAndRerunsTheArchive 127
  BatchSlurm.JobArrayBuildsTheArchive 115
  PydicomTestFiles.DecodeAgreesWithPydicomOrRejectsCleanly 97
  BatchArchiveTest.FiltersSelectSeriesAndListTheRestWithTheReason 59
  WorkingSetTest.RealHeadsMeetTheRelativeBar 57
  BatchArchiveTest.RunsKilledAtRandomMomentsResumeToCompleteStores 57
  DicomWeb.RetrievedSeriesImportsToTheSameStoreAsTheLocalFiles 55
  BatchArchiveTest.AChangedFileFailsItsItemUntilPlannedAgain 48
  bench_accuracy_quick 43)

# octoray_apply_test_costs(TESTS...): the COST of each of TESTS that the list names.
function(octoray_apply_test_costs)
  set(left ${OCTORAY_TEST_COSTS})
  while(left)
    list(POP_FRONT left test seconds)
    list(FIND ARGN "${test}" index)  # not IN_LIST: ctest reads this with the old policies
    if(index GREATER -1)
      set_tests_properties(${test} PROPERTIES COST ${seconds})
    endif()
  endwhile()
endfunction()
