MODULE TestbedTask_L
  ! Task T_ROB_L (the left arm) of the testbed: its data for TestbedMotion and its
  ! entry routine. Load into task T_ROB_L only, with TestbedMotion.mod next to it.
  !
  ! The file this task reads, on the RAM disk: fixed per task, the name the driver
  ! uploads to (drivers/yumi/yumi_controller.py, program_file). The other arm's task
  ! reads its own file, so the two programs never share one.
  CONST string tb_name := "testbed_T_ROB_L.bin";
  ! The pusher. tframe is overwritten from every program's header (the calibration
  ! file's tool_z_mm); the load is the pusher's own: WEIGH IT on day one and set mass
  ! (kg) and the centre of gravity (mm, tool0 frame) here before the first motion.
  TASK PERS tooldata tool_pusher := [TRUE,[[0,0,100],[1,0,0,0]],[0.1,[0,0,50],[1,0,0,0],0,0,0]];
  ! The floor (mm, world frame = wobj0, the frame the driver's targets use): no
  ! MoveJ/MoveL target below it (checked in the file) and no TCP below it, anywhere
  ! (the world zone tb_wz_floor).
  CONST num tb_floor_z := 0;
  ! This arm's world zone (TestbedMotion, tb_zones; robot/README.md, "The zones"): below
  ! tb_zone_z (mm, world) the TCP of tool_pusher must stay inside the xy box from
  ! tb_zone_lo to tb_zone_hi (x, y in mm, world; z unused). SET THESE FROM YOUR TABLE at
  ! install: the calibration's table_box_mm must lie inside the box, the other arm's
  ! workspace outside it, and tb_zone_z at or below the calibration's z_travel_mm.
  CONST pos tb_zone_lo := [125,25,0];
  CONST pos tb_zone_hi := [495,395,0];
  CONST num tb_zone_z := 80;

  PROC main()
    tb_run;
  ENDPROC
ENDMODULE
